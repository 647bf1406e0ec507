"""Coupled inertia for the simulator: a dense H(q) and the exact stick-slip step of its joints.

The simulator (`manus.plants.simulator`) asks a structure's `mass(pose, p)` for an object with
`solve`, `friction`, `diagonal` and `minus_diagonal`; MANUS-2 answers with a closed-form 2×2
(`Sym2`), independent axes with a diagonal. A serial chain's H(q) is a dense n×n matrix:
`Dense` holds it, solves with its Cholesky factor, and solves the friction step below.

## The friction step (one implicit sub-step, Moreau)

With the velocity v* the smooth torques would give after the sub-step h and the friction
levels per joint (f_i ∈ [−lo_i, hi_i]), the friction torque f solves the box-constrained QP

    min_f ½ fᵀ W f − fᵀ v*    over −lo ≤ f ≤ hi,    W = h H⁻¹,

and the new velocity is v = v* − W f: a joint whose f lies strictly inside its box comes to rest
exactly (stiction), one at a bound slides with f = hi (forward) or −lo (backward). For coupled
joints (H not diagonal) one joint's stiction moves the others, so the box is solved jointly:

1. projected Gauss–Seidel (`SWEEPS` sweeps, each joint in turn minimizes over its own f_i with
   the others held, clipped to its box), from the clipped unconstrained optimum f = H v*/h;
2. a polish: the joints PGS left inside their boxes are taken as free, the others held at their
   bounds, and the free ones solved exactly (a linear system in W's free block). If the result
   satisfies every optimality condition (free f inside the box, the bound joints sliding the way
   their bound says: v_i ≥ 0 at hi, v_i ≤ 0 at −lo) it is the exact solution, to rounding;
3. otherwise the better of the two (PGS's iterate, the clipped polish) starts the next round;
   `ROUNDS` rounds in all (a fixed amount of work: the sub-step is one compiled function).

Tolerance (tests/plants/test_serial_sim.py: 200 random Panda configurations with random
armatures, levels (some zero) and velocities, 0 to 7 joints stuck, against a bounded
least-squares solution by scipy's BVLS): every case confirmed exact by the polish, |f − f*| below
1e-13 of the levels (rounding). PGS alone after the same 30 sweeps errs by up to 3e-4 of the
levels (median 4e-16): the polish is what makes the step exact when several coupled joints stick.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

SWEEPS = 10  # projected Gauss–Seidel sweeps before each polish
ROUNDS = 3  # rounds of sweeps and polish (a confirmed polish ends the work: later rounds keep it)
KKT_TOL = 1e-9  # relative: a bound joint may "slide the wrong way" by this much of the speeds' scale


def _stack(x) -> Array:
    return jnp.stack(x) if isinstance(x, (tuple, list)) else jnp.asarray(x)


def _tuple(x: Array) -> tuple:
    return tuple(x[i] for i in range(x.shape[0]))


def pgs(W: Array, v: Array, lo: Array, hi: Array, f: Array, sweeps: int = SWEEPS) -> Array:
    """`sweeps` sweeps of projected Gauss–Seidel on min ½ fᵀWf − fᵀv over −lo ≤ f ≤ hi, from f."""
    n = v.shape[0]
    d = jnp.diagonal(W)

    def sweep(_, f):
        for i in range(n):  # each joint's own minimum, the others held
            fi = f[i] + (v[i] - W[i] @ f) / d[i]
            f = f.at[i].set(jnp.clip(fi, -lo[i], hi[i]))
        return f

    return jax.lax.fori_loop(0, sweeps, sweep, f)


def _objective(W: Array, v: Array, f: Array) -> Array:
    return 0.5 * f @ W @ f - f @ v


def _on_active_set(W: Array, v: Array, lo: Array, hi: Array, f: Array) -> tuple[Array, Array]:
    """The joints free in `f` (strictly inside their box) solved exactly, the others held: (x, free)."""
    n = v.shape[0]
    free = (f > -lo) & (f < hi)
    M = jnp.where(free[:, None] & free[None, :], W, jnp.eye(n, dtype=W.dtype))
    fixed = jnp.where(free, 0.0, f)
    x = jnp.linalg.solve(M, jnp.where(free, v - W @ fixed, f))
    return jnp.where(free, x, f), free


def optimal(W: Array, v: Array, lo: Array, hi: Array, x: Array, free: Array) -> Array:
    """Whether x satisfies the optimality conditions of the box QP on the active set `free`: the
    free joints inside their box, a joint held at hi not moving backward, one at −lo not forward
    (lo = hi = 0: no friction, nothing to check)."""
    vel = v - W @ x  # the new velocity
    scale = KKT_TOL * (jnp.max(jnp.abs(v)) + jnp.max(jnp.abs(W)) * jnp.max(jnp.abs(x)) + 1e-300)
    inside = jnp.where(free, (x >= -lo) & (x <= hi), True)
    at_hi, at_lo = ~free & (x >= hi), ~free & (x <= -lo)
    sliding = jnp.where(at_hi & ~at_lo, vel >= -scale, True) & jnp.where(at_lo & ~at_hi, vel <= scale, True)
    return jnp.all(inside & sliding)


def box_friction(
    H: Array, v: Array, lo: Array, hi: Array, dt, rounds: int = ROUNDS, sweeps: int = SWEEPS
) -> tuple[Array, Array]:
    """(f, exact): the friction torque of one implicit step of length `dt` for inertia H (n, n),
    velocity v* (n,), levels lo, hi ≥ 0 (n,); `exact` says whether a polish confirmed it (else f
    is the best iterate found)."""
    W = dt * jnp.linalg.inv(H)
    W = 0.5 * (W + W.T)
    f0 = jnp.clip(H @ v / dt, -lo, hi)  # every joint stopped, clipped to its box

    def round_(state):
        f, _, r = state
        g = pgs(W, v, lo, hi, f, sweeps)
        x, free = _on_active_set(W, v, lo, hi, g)
        exact = optimal(W, v, lo, hi, x, free)
        x = jnp.clip(x, -lo, hi)
        better = _objective(W, v, x) < _objective(W, v, g)  # a failed polish may still be the better start
        return jnp.where(exact | better, x, g), exact, r + 1

    # the clipped start is often exact already (every joint sliding, or all stuck): check it first
    x, free = _on_active_set(W, v, lo, hi, f0)
    start = optimal(W, v, lo, hi, x, free)
    f, done, _ = jax.lax.while_loop(
        lambda s: ~s[1] & (s[2] < rounds), round_, (jnp.where(start, jnp.clip(x, -lo, hi), f0), start, 0)
    )
    return f, done


class Dense(NamedTuple):
    """A dense symmetric positive definite matrix H (n, n) in the simulator's joint-tuple form."""

    H: Array

    def matrix(self) -> Array:
        return self.H

    def diagonal(self) -> tuple:
        return _tuple(jnp.diagonal(self.H))

    def minus_diagonal(self, x) -> Dense:
        return Dense(self.H - jnp.diag(_stack(x)))

    def solve(self, r) -> tuple:
        """H⁻¹ r, by the Cholesky factor."""
        factor = jax.scipy.linalg.cho_factor(self.H)
        return _tuple(jax.scipy.linalg.cho_solve(factor, _stack(r)))

    def friction(self, v, lo, hi, dt) -> tuple:
        """argmin ½ fᵀ W f − fᵀ v over −lo ≤ f ≤ hi, W = dt·H⁻¹ (see the module docstring)."""
        f, _ = box_friction(self.H, _stack(v), _stack(lo), _stack(hi), dt)
        return _tuple(f)
