"""Composite adaptation: the tracking error plus the prediction error of a filtered torque model,
with a least-squares gain (Slotine and Li, "Composite adaptive control of robot manipulators",
Automatica 25(4), 1989).

The plain law learns only through the tracking error s, which the closed loop has already
low-passed (corner K_D/H ≈ 14 rad/s on MANUS-2) and which vanishes once tracking is good. The
composite law adds what the torque itself says about the parameters:

    â̇ = −P (Yᵀ s + κ Wᵀ e),   e = W â − τ_f,   d/dt P⁻¹ = κ WᵀW − β(t) P⁻¹,   P(0) = Γ

with τ_f the commanded torque through the low-pass f(p) = λ_f/(p + λ_f) and W the regressor of the
same filtered torque. W needs no acceleration: writing H q̈ = d/dt(H q̇) − Ḣ q̇,

    τ = d/dt(Z₁ a) + Z₂ a,   Z₁(q, q̇) a = H(q) q̇,
                             Z₂(q, q̇) a = −Ḣ(q, q̇) q̇ + C(q, q̇) q̇ + Σ other effects (q, q̇)

and filtering commutes with d/dt for a run that starts at rest, so

    W = d/dt(f·Z₁) + f·Z₂,   W a = τ_f.

Ḣ comes from forward-mode differentiation of the structure's H(q) along q̇; the other effects'
columns come from their own torques at the (lag-compensated) *estimated* velocity: this is a
model of the plant's torque balance, not of the reference.

Why a least-squares gain: on the thesis's complex trajectory each joint moves at one frequency
and one amplitude, so its viscous column q̇ and its Coulomb column sgn(q̇) are 90 % correlated
and λ_min(∫YᵀY) is 0.35 after 4 s against ≈ 120 for the inertias. A constant gain converges along
that valley 10–100 times slower than elsewhere; P⁻¹ accumulates the information, so every
direction converges at once (P is the inverse of Γ⁻¹ + κ ∫WᵀW). The filter must pass the
harmonics of sgn(q̇) that tell the two apart: λ_f = 50 rad/s by default. With β = 0 the gain only
shrinks; bounded-gain forgetting β(t) = β₀ (1 − tr P / tr Γ) keeps it alive for long runs.
Lyapunov: V = ½ sᵀHs + ½ ãᵀP⁻¹ã gives V̇ = −sᵀK_D s − ½ κ |W ã|² − ½ β ãᵀP⁻¹ã ≤ 0.

Noise: the command carries the velocity estimate's noise through −K_D s, and W carries the same
noise, so the prediction error of a noisy estimate is biased (closed-loop identification). With
the first difference (quantization noise ≈ 0.03 rad/s rms) the composite law's estimates are off
by up to 10 %; use a Kalman filter (the default `kalman_cv`): then every parameter of rigid,
viscous, coulomb comes within 2 % in under 2 s on the complex trajectory (measured).

Discretization, at the control rate T: each filter is exact for an input held over the period
before each sample, x_f ← x_f + (1 − e^{−λ_f T}) (x − x_f); d/dt(f·Z₁) is the difference of
consecutive filter outputs over T and f·Z₂ their mean, both at the middle of the period (W and τ_f
then share one discrete filter, so the inertias come out unscaled; taking f·Z₂ half a period late
instead biased b2 and Fc2 by ∓1.7 %, measured). The information update R ← R + T κ WᵀW is done on P
by the Woodbury identity (an n×n inverse). Timing: the command of tick k acts over the period after
it, from `lead` − T/2 on, while the filters put each sample over the period before it; the filtered
torque that explains the motion at tick k is therefore τ_f taken back by `lead` + T/2, done along
its own derivative λ_f (τ − τ_f) (first order, λ_f (lead + T/2) ≪ 1). With these, the prediction
error of the true parameters on a simulated run is about 1e-3 N·m (tested); one period off, several
times more, and the viscous estimate biased by −δ a ω² as in the tracking term.

Vectorization: the state keeps every entry of f·Z₁, f·Z₂ and of P's upper triangle as its own
array, and the step works on them as scalars (sums of products, the n×n inverse in closed form,
only the upper triangle of the symmetric P computed), with MANUS-2's Z columns written out. Under
`vmap` each entry is then a batch vector; the matrix form (P Wᵀ, W P Wᵀ, … on (P, P) and (n, P)
arrays per trial) became tiny batched matrix products, and even as broadcast-and-sum its
reductions over short inner axes took 3× the time of the whole gradient controller (measured:
2300 -> 820 ns CPU per trial-step of the composite closed loop vmapped over 200 trials).
`CompositeState.P` gives the gain as a matrix.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import Array

from manus.adaptive.regressors import Regressor
from manus.plants.errors import ModelError


def upper_triangle(m: int) -> tuple[tuple[int, int], ...]:
    """The upper triangle (i ≤ j) of an m×m matrix, row by row: the order of `CompositeState.gain`."""
    return tuple((i, j) for i in range(m) for j in range(i, m))


class CompositeState(NamedTuple):
    """Entry by entry (structure of arrays; see the module docstring)."""

    z1: tuple  # f·Z₁: its n·P entries, row by row (joint by joint), each an array ()
    z2: tuple  # f·Z₂, the same
    tau: Array  # τ_f (n,)
    gain: tuple  # the least-squares gain P: its upper triangle, row by row (`upper_triangle`)

    @property
    def P(self) -> Array:
        """The gain as a symmetric matrix (P, P) (with any leading axes the entries carry)."""
        return symmetric(self.gain, jnp.ndim(self.gain[0]))

    @property
    def diagonal(self) -> Array:
        """The gain's diagonal (P,), without forming the matrix."""
        m = int(round((math.sqrt(8 * len(self.gain) + 1) - 1) / 2))
        return jnp.stack([g for g, (i, j) in zip(self.gain, upper_triangle(m), strict=True) if i == j], -1)


def symmetric(upper: tuple, axis: int = 0) -> Array:
    """The symmetric m×m matrix whose upper triangle, row by row (`upper_triangle`), is `upper`; its two
    axes at `axis` and `axis` + 1 of the result (a non-negative position among the entries' axes)."""
    m = int(round((math.sqrt(8 * len(upper) + 1) - 1) / 2))
    e = dict(zip(upper_triangle(m), upper, strict=True))
    return jnp.stack([jnp.stack([e[min(i, j), max(i, j)] for j in range(m)], axis) for i in range(m)], axis)


def _inverse(S: list) -> list:
    """S⁻¹ of a small symmetric matrix given as nested lists of scalars; 1×1 and 2×2 in closed form
    (no LAPACK call under vmap)."""
    n = len(S)
    if n == 1:
        return [[1.0 / S[0][0]]]
    if n == 2:
        det = S[0][0] * S[1][1] - S[0][1] * S[1][0]
        return [[S[1][1] / det, -S[0][1] / det], [-S[1][0] / det, S[0][0] / det]]
    Si = jnp.linalg.inv(jnp.stack([jnp.stack(row) for row in S]))
    return [[Si[a, b] for b in range(n)] for a in range(n)]


def _gain_update(gain: tuple, w: list, c) -> tuple:
    """P − P Wᵀ (c I + W P Wᵀ)⁻¹ W P (Woodbury) entry by entry, for P symmetric given by its upper
    triangle and W (n, m) as nested lists of scalars; the upper triangle of the result."""
    n, m = len(w), len(w[0])
    entry = dict(zip(upper_triangle(m), gain, strict=True))
    p = lambda i, j: entry[min(i, j), max(i, j)]
    pw = [[sum(p(i, k) * w[a][k] for k in range(m)) for a in range(n)] for i in range(m)]  # P Wᵀ (m, n)
    S = [[sum(w[a][k] * pw[k][b] for k in range(m)) + (c if a == b else 0.0) for b in range(n)] for a in range(n)]
    inv = _inverse(S)
    g = [[sum(pw[i][a] * inv[a][b] for a in range(n)) for b in range(n)] for i in range(m)]  # P Wᵀ S⁻¹ (m, n)
    return tuple(p(i, j) - sum(g[i][b] * pw[j][b] for b in range(n)) for i, j in upper_triangle(m))


class Composite(eqx.Module):
    """Composite adaptation with a least-squares gain (see the module docstring). The model and
    the boundary layer are the controller's regressor's; P(0) is the controller's Γ."""

    bandwidth: float = 50.0  # λ_f [rad/s]
    weight: float = 50.0  # κ [rad/(N·m·s)]
    forgetting: float = 0.0  # β₀ [1/s] of bounded-gain forgetting; 0: none

    def __check_init__(self):
        for name, value, ok in (
            ("bandwidth", self.bandwidth, lambda x: x > 0),
            ("weight", self.weight, lambda x: x > 0),
            ("forgetting", self.forgetting, lambda x: x >= 0),
        ):
            if isinstance(value, (int, float)) and not (ok(value) and math.isfinite(value)):
                raise ModelError(
                    f"composite {name} must be {'>= 0' if name == 'forgetting' else 'positive'} and finite, got {value}"
                )

    @staticmethod
    def _z(regressor: Regressor, q, qd, theta):
        """(Z₁ θ, Z₂ θ): generalized momentum and the acceleration-free rest of the torque."""
        model = regressor.model
        s, p = model.structure, model.unvector(theta)
        H, H_dot = jax.jvp(lambda x: s.inertia(x, p), (q,), (qd,))
        z1 = H @ qd
        z2 = -H_dot @ qd + s.coriolis(q, qd, p) @ qd
        if s.rigid_gravity:  # a serial chain's rigid effect holds gravity, g(q)
            zero = jnp.zeros_like(qd)
            z2 = z2 + s.rigid_torque(q, zero, zero, p)
        for e in model.effects:
            if not e.inertial:
                z2 = z2 + model.effect_torque(e, q, qd, jnp.zeros_like(qd), p, regressor.boundary)
        return z1, z2

    @classmethod
    def columns(cls, regressor: Regressor, q, qd) -> tuple[list, list]:
        """(Z₁, Z₂) = ∂(Z₁ θ)/∂θ, ∂(Z₂ θ)/∂θ as nested lists [joint][parameter] of scalars.

        The rigid columns of a structure that writes them out (`Structure.momentum_columns`:
        MANUS-2's, c = cos(q2 − q1), s = sin(q2 − q1): Z₁ = H q̇ per parameter; in Z₂, −Ḣ q̇ + C q̇
        leaves ∓s q̇1 q̇2 in the a2 column) are its own, the other effects' come from forward-mode
        differentiation of their torques (elementwise in the joints). Other structures: forward
        mode through `_z` (whose H q̇ products are tiny matrix products under `vmap`)."""
        model, names = regressor.model, regressor.names
        s, n = model.structure, regressor.n_joints
        theta0 = jnp.zeros(len(names), jnp.result_type(qd, float))
        written = s.momentum_columns(q, qd)
        if written is None:
            z1, z2 = jax.jacfwd(lambda th: cls._z(regressor, q, qd, th))(theta0)
            Z1, Z2 = ([[z[a, k] for k in range(len(names))] for a in range(n)] for z in (z1, z2))
            return Z1, Z2
        z1, z2 = written
        zero = jnp.zeros_like(q[0])  # Z₁ of the other effects: they hold no momentum
        if any(not e.inertial for e in model.effects):

            def rest(th):
                p = model.unvector(th)
                return sum(
                    model.effect_torque(e, q, qd, jnp.zeros_like(qd), p, regressor.boundary)
                    for e in model.effects
                    if not e.inertial
                )

            Zo = jax.jacfwd(rest)(theta0)
            z2.update({k: (Zo[0, i], Zo[1, i]) for i, k in enumerate(names) if k not in z2})
        z1.update({k: (zero, zero) for k in names if k not in z1})
        Z1, Z2 = ([[z[k][a] for k in names] for a in range(n)] for z in (z1, z2))
        return Z1, Z2

    def init(self, regressor: Regressor, gamma: Array) -> CompositeState:
        n, m = regressor.n_joints, len(regressor.names)
        gamma = jnp.asarray(gamma, float)
        zeros = (jnp.zeros((), gamma.dtype),) * (n * m)
        return CompositeState(
            zeros, zeros, jnp.zeros(n), tuple(gamma[i] if i == j else 0.0 * gamma[i] for i, j in upper_triangle(m))
        )

    def step(self, state: CompositeState, regressor: Regressor, q, qd, tau, gamma: Array, lead: float, dt: float):
        """Advance the filters and the gain by one tick -> (state, W (n, P), τ_f (n,)).

        q, q̇: the motion now; tau: the command of this tick, which acts `lead` s from now;
        gamma: the controller's Γ (P(0), and the bound of the forgetting)."""
        n, m = regressor.n_joints, len(regressor.names)
        z1, z2 = ([x for row in z for x in row] for z in self.columns(regressor, q, qd))  # row by row
        k = 1.0 - jnp.exp(-self.bandwidth * dt)
        z1f = tuple(old + k * (new - old) for old, new in zip(state.z1, z1, strict=True))
        z2f = tuple(old + k * (new - old) for old, new in zip(state.z2, z2, strict=True))
        tau_f = state.tau + k * (tau - state.tau)
        # both at the middle of the period
        w = [
            [
                (z1f[a * m + i] - state.z1[a * m + i]) / dt + 0.5 * (z2f[a * m + i] + state.z2[a * m + i])
                for i in range(m)
            ]
            for a in range(n)
        ]
        # R = P⁻¹ gains T κ WᵀW (Woodbury: an n×n inverse), then bounded-gain forgetting
        gain = _gain_update(state.gain, w, 1.0 / (dt * self.weight))
        trace = sum(g for g, (i, j) in zip(gain, upper_triangle(m), strict=True) if i == j)
        beta = self.forgetting * jnp.maximum(0.0, 1.0 - trace / jnp.sum(gamma))
        gain = tuple(g * (1.0 + dt * beta) for g in gain)
        W = jnp.stack([jnp.stack(row) for row in w])
        return CompositeState(z1f, z2f, tau_f, gain), W, tau_f - (lead + 0.5 * dt) * self.bandwidth * (tau - tau_f)

    def direction(self, state: CompositeState, grad: Array, W: Array, tau_f: Array, theta: Array) -> Array:
        """P (Yᵀ s + κ Wᵀ (W θ − τ_f)), shape (P,), with grad = Yᵀ s: â moves by −T times this.
        Sums of products, P entry by entry."""
        n, m = W.shape
        e = [sum(W[a, k] * theta[k] for k in range(m)) - tau_f[a] for a in range(n)]  # prediction error
        g = [grad[k] + self.weight * sum(W[a, k] * e[a] for a in range(n)) for k in range(m)]
        entry = dict(zip(upper_triangle(m), state.gain, strict=True))
        return jnp.stack([sum(entry[min(i, k), max(i, k)] * g[k] for k in range(m)) for i in range(m)])
