"""Joint structures: how the joints are coupled through inertia (the `rigid` effect).

A structure knows the inertia matrix H(q), the Coriolis/centripetal matrix C(q, q̇) written so
that Ḣ − 2C is skew-symmetric (the Slotine–Li form), and how to solve the small linear systems
of the simulator in closed form (no LAPACK call per step: see `../shared/notes`).

Two structures:

- `Manus2`: the thesis's planar 2-link arm in *absolute* joint angles (both measured from the
  base frame, eqs. C.1–C.5). Rigid parameters a1, a2, a3 [kg m²]:

      H(q) = [[a1, a2 cos(q2 − q1)], [a2 cos(q2 − q1), a3]]
      C(q, q̇) q̇ = [−a2 sin(q2 − q1) q̇2², a2 sin(q2 − q1) q̇1²]

- `Axis(n)`: n independent single-axis joints (like the EMPS drive); one inertia (or mass)
  M_i per joint and no coupling.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jax import Array


class Structure(eqx.Module):
    """Abstract joint structure. Arrays are per joint, shape `(n_joints,)`."""

    name: ClassVar[str]
    n_joints: eqx.AbstractVar[int]

    @property
    @abc.abstractmethod
    def rigid_names(self) -> tuple[str, ...]:
        """Names of the rigid-body parameters, in regressor column order."""

    @property
    @abc.abstractmethod
    def rigid_defaults(self) -> tuple[float, ...]:
        """Default values of the rigid-body parameters (the thesis's where it has them)."""

    @abc.abstractmethod
    def inertia(self, q: Array, p: dict) -> Array:
        """H(q), shape (n, n)."""

    @abc.abstractmethod
    def coriolis(self, q: Array, qd: Array, p: dict) -> Array:
        """C(q, q̇), shape (n, n), with Ḣ − 2C skew-symmetric."""

    @abc.abstractmethod
    def solve(self, H: Array, r: Array) -> Array:
        """H⁻¹ r in closed form."""

    @abc.abstractmethod
    def friction_solve(self, H: Array, vstar: Array, lo: Array, hi: Array, dt) -> Array:
        """The friction torque f ∈ [−lo, hi] of one implicit time step.

        Solves min_f ½ fᵀ W f − fᵀ v* over the box, W = dt·H⁻¹: the exact Moreau step for
        Coulomb-type friction. The new velocity is v* − W f; a joint whose needed friction lies
        inside its bounds comes to rest exactly (stiction, no creep).
        """

    def rigid_torque(self, q: Array, qd: Array, qdd: Array, p: dict) -> Array:
        """H(q) q̈ + C(q, q̇) q̇."""
        return self.inertia(q, p) @ qdd + self.coriolis(q, qd, p) @ qd


class Manus2(Structure):
    """The MANUS-2 planar 2-link arm in absolute joint angles (thesis eqs. 3.2–3.4, C.1–C.5)."""

    name: ClassVar[str] = "manus2"
    n_joints: int = eqx.field(default=2, static=True)

    @property
    def rigid_names(self):
        return ("a1", "a2", "a3")

    @property
    def rigid_defaults(self):
        return (0.349, 0.241, 0.246)  # kg m², thesis §3.5.5 and eq. 3.13

    def inertia(self, q, p):
        c = jnp.cos(q[1] - q[0])
        h12 = p["a2"] * c
        return jnp.stack([jnp.stack([p["a1"] + 0 * c, h12]), jnp.stack([h12, p["a3"] + 0 * c])])

    def coriolis(self, q, qd, p):
        s = p["a2"] * jnp.sin(q[1] - q[0])
        z = 0 * s
        return jnp.stack([jnp.stack([z, -s * qd[1]]), jnp.stack([s * qd[0], z])])

    def solve(self, H, r):
        det = H[0, 0] * H[1, 1] - H[0, 1] * H[1, 0]
        return jnp.stack([H[1, 1] * r[0] - H[0, 1] * r[1], H[0, 0] * r[1] - H[1, 0] * r[0]]) / det

    def friction_solve(self, H, vstar, lo, hi, dt):
        # Box-constrained convex QP in two variables, solved exactly: the unconstrained
        # minimiser if it is feasible, otherwise the best of the four edge minimisers
        # (each edge fixes one force at a bound and clips the other's 1-D optimum).
        g = H @ vstar / dt  # unconstrained optimum W⁻¹ v*
        W = dt * jnp.stack([self.solve(H, jnp.array([1.0, 0.0])), self.solve(H, jnp.array([0.0, 1.0]))], 1)
        W = W.astype(vstar.dtype)

        def objective(f):
            return 0.5 * f @ (W @ f) - f @ vstar

        cands = []
        for i, j in ((0, 1), (1, 0)):
            for bound in (-lo[i], hi[i]):
                fj = jnp.clip((vstar[j] - W[j, i] * bound) / W[j, j], -lo[j], hi[j])
                f = jnp.zeros(2, vstar.dtype).at[i].set(bound).at[j].set(fj)
                cands.append(f)
        cands = jnp.stack(cands)
        best = cands[jnp.argmin(jnp.stack([objective(f) for f in cands]))]
        inside = jnp.all((g >= -lo) & (g <= hi))
        return jnp.where(inside, g, best)


class Axis(Structure):
    """`n_joints` independent single axes (rotary or prismatic), one inertia M_i each."""

    name: ClassVar[str] = "axis"
    n_joints: int = eqx.field(default=1, static=True)

    @property
    def rigid_names(self):
        return tuple(f"M{i + 1}" for i in range(self.n_joints))

    @property
    def rigid_defaults(self):
        return (1.0,) * self.n_joints  # thesis eq. 4.1: m = 1 kg near the workspace centre

    def inertia(self, q, p):
        return jnp.diag(jnp.stack([p[k] + 0 * q[0] for k in self.rigid_names]))

    def coriolis(self, q, qd, p):
        return jnp.zeros((self.n_joints, self.n_joints), qd.dtype)

    def solve(self, H, r):
        return r / jnp.diagonal(H)

    def friction_solve(self, H, vstar, lo, hi, dt):
        return jnp.clip(jnp.diagonal(H) * vstar / dt, -lo, hi)


def structure_named(name: str, n_joints: int) -> Structure:
    """The structure called `name` ("manus2" or "axis") with `n_joints` joints."""
    if name == "manus2":
        if n_joints != 2:
            raise ValueError(f"structure manus2 has 2 joints, not {n_joints}")
        return Manus2()
    if name == "axis":
        return Axis(n_joints=n_joints)
    raise ValueError(f"unknown structure {name!r}: expected 'manus2' or 'axis'")
