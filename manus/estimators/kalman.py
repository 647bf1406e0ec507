"""Kinematic Kalman filters: constant velocity (`kalman_cv`) and constant acceleration (`kalman_ca`).

Each joint is its own filter on the state x = (q, q̇) or (q, q̇, q̈), driven by white noise of
spectral density `q` on its highest derivative (the discretized continuous white-noise model):

    x_k = F x_{k−1} + w,   F_ij = T^(j−i)/(j−i)!,   E[w wᵀ] = Q = q ∫₀ᵀ e^{Fs} e_d e_dᵀ e^{Fᵀs} ds
    y_k = q_k = x_k[0] + v,   E[v²] = R = Δ²/12      (uniform quantization by an encoder of step Δ)

Units: `q` is [position² / s³] for the constant-velocity model (white acceleration) and
[position² / s⁵] for the constant-acceleration model (white jerk); Δ is in position units.

The bandwidth of the filter is ω = (q / (R T))^(1/2d) (the continuous steady-state filter of a
d-fold integrator has its poles on a Butterworth pattern of that radius), so q = ω^(2d) R T.
The default ω gives the velocity the quantization noise of the thesis's filtered first
difference (`manus.estimators.linear`): about 290 rad/s (constant acceleration) and 460 rad/s
(constant velocity) at 1 kHz. It scales with Δ, so the same default suits radians and metres.

The covariance update is the Joseph form, P = (I − K H) P̄ (I − K H)ᵀ + K R Kᵀ, which stays
symmetric positive definite. The filter starts from the steady-state covariance (the solution of
the discrete algebraic Riccati equation), so there is no start-up transient beyond the one of the
unknown initial velocity; `steady=True` keeps only the steady-state gain K∞ (no covariance in the
state: the cheapest filter, identical to the full one once P has converged).

The step is written per joint on scalars: the entry axes of x and P are moved to the front, each
estimate and each entry of P taken out as its own array, updated with F's entries as Python
constants, and stacked back. Under `vmap` each one is a batch vector, where the matrix form's
F x, F P Fᵀ and Joseph products become tiny batched matrix products (measured, 2 joints vmapped
over 200 trials, the filter alone: 115–155 -> 25 ns CPU per trial-step for constant velocity,
215–265 -> 60–85 for constant acceleration; in the convergence batch of `manus bench converge`,
moving the entry axes to the front before slicing took the whole closed loop from 550–670 to
470–490 ns, as fast as keeping every entry apart in the state, which instead made a jitted call
from Python pay for 5–9 state arrays: +17 µs p50 for constant acceleration). It agrees with the
matrix form to rounding (tested against filterpy and a numpy matrix filter)."""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import scipy.linalg
from jax import Array

from manus.estimators.base import Estimate, Estimator
from manus.estimators.linear import equal_noise_bandwidth, quantization_variance


def transition(order: int, dt: float) -> np.ndarray:
    """F of a chain of `order` integrators over one period: F_ij = T^(j−i)/(j−i)! for j ≥ i."""
    return np.array(
        [[dt ** (j - i) / math.factorial(j - i) if j >= i else 0.0 for j in range(order)] for i in range(order)]
    )


def white_noise_covariance(order: int, dt: float) -> np.ndarray:
    """Q / q: the covariance that unit-density white noise on the highest derivative adds over one
    period, Q_ij = T^(2d−1−i−j) / ((d−1−i)! (d−1−j)! (2d−1−i−j))."""
    d = order
    return np.array(
        [
            [
                dt ** (2 * d - 1 - i - j)
                / (math.factorial(d - 1 - i) * math.factorial(d - 1 - j) * (2 * d - 1 - i - j))
                for j in range(d)
            ]
            for i in range(d)
        ]
    )


def bandwidth_noise(order: int, dt: float, r: float, bandwidth: float) -> float:
    """The process noise density q that gives the filter the bandwidth ω [rad/s]: ω^(2d) R T."""
    return bandwidth ** (2 * order) * r * dt


@functools.cache
def default_bandwidth(order: int, dt: float) -> float:
    """ω [rad/s] at which the filter's velocity noise equals the thesis filter's."""

    def design(w):
        F = transition(order, dt)
        _, K = steady_state(order, dt, bandwidth_noise(order, dt, 1.0, w), 1.0)
        return (np.eye(order) - np.outer(K, np.eye(order)[0])) @ F, K

    return equal_noise_bandwidth(design, dt)


def steady_state(order: int, dt: float, q: float, r: float) -> tuple[np.ndarray, np.ndarray]:
    """(P∞ posterior, K∞) of the scalar-measurement filter, from the discrete Riccati equation.

    Solved in scaled states x̃_i = T^i x_i (every state in position units), where F̃ and Q̃ / R
    are of order one whatever the units and the sample rate."""
    s = dt ** np.arange(order)
    f = transition(order, dt) * s[:, None] / s[None, :]
    qs = white_noise_covariance(order, dt) * np.outer(s, s) * q / r
    h = np.zeros((1, order))
    h[0, 0] = 1.0
    prior = scipy.linalg.solve_discrete_are(f.T, h.T, qs, np.eye(1))
    k = prior[:, :1] / (prior[0, 0] + 1.0)
    post = (np.eye(order) - k @ h) @ prior @ (np.eye(order) - k @ h).T + k @ k.T
    return r * post / np.outer(s, s), (k[:, 0] / s)


def _pairs(order: int) -> tuple[tuple[int, int], ...]:
    """The upper triangle (i ≤ j) of a d×d covariance, row by row (the entries a step computes)."""
    return tuple((i, j) for i in range(order) for j in range(i, order))


def _combination(terms):
    """Σ c·v over (c, v) with Python-float c: zeros skipped, ones not multiplied."""
    out = None
    for c, v in terms:
        if c == 0.0:
            continue
        term = v if c == 1.0 else c * v
        out = term if out is None else out + term
    assert out is not None, "a combination with every coefficient zero"
    return out


class KalmanState(NamedTuple):
    x: Array  # state estimates (n, d): position, velocity[, acceleration]
    P: Array | None  # posterior covariances (n, d, d); None for the steady-state filter


class KinematicKalman(Estimator):
    """A Kalman filter per joint on a chain of integrators (see the module docstring).

    `order` = 2 (constant velocity) or 3 (constant acceleration, which also gives q̈);
    `q` the process noise density (the tuning knob); `r` = Δ²/12 the measurement variance
    (default: the thesis's encoder, Δ = 2π/131072 rad).

    The step works on scalars per joint (see the module docstring); the covariance it stores is
    exactly symmetric (the upper triangle computed, mirrored).
    """

    dt: float = eqx.field(static=True)
    order: int = eqx.field(static=True)
    steady: bool = eqx.field(static=True)
    q: Array
    r: Array
    F: Array
    Q1: Array  # Q / q
    P0: Array  # steady-state posterior covariance (d, d), the starting one
    K: Array  # steady-state gain (d,)

    def __init__(
        self,
        dt: float = 1e-3,
        order: int = 3,
        q: float | None = None,
        r: float = quantization_variance(),
        steady: bool = False,
    ):
        if order not in (2, 3):
            raise ValueError(f"order must be 2 (constant velocity) or 3 (constant acceleration), not {order}")
        self.dt, self.order, self.steady = float(dt), int(order), bool(steady)
        q = bandwidth_noise(order, dt, r, default_bandwidth(order, dt)) if q is None else float(q)
        if not (q > 0 and r > 0):
            raise ValueError(f"process noise q and measurement variance r must be positive, got {q:g}, {r:g}")
        self.q, self.r = jnp.asarray(q), jnp.asarray(float(r))
        self.F = jnp.asarray(transition(order, dt))
        self.Q1 = jnp.asarray(white_noise_covariance(order, dt))
        P0, K = steady_state(order, dt, q, r)
        self.P0, self.K = jnp.asarray(P0), jnp.asarray(K)

    def init(self, q0):
        q0 = jnp.asarray(q0, float)
        x = jnp.zeros(q0.shape + (self.order,)).at[..., 0].set(q0)
        return KalmanState(x, None if self.steady else jnp.broadcast_to(self.P0, q0.shape + self.P0.shape))

    def _predict(self, x):
        """x̄ = F x, F_ij = T^(j−i)/(j−i)! (Python constants)."""
        F, d = transition(self.order, self.dt), self.order
        return tuple(_combination((F[i, j], x[j]) for j in range(i, d)) for i in range(d))

    def step(self, state, q, tau=None):
        d = self.order
        xt = jnp.moveaxis(state.x, -1, 0)  # entries first: each a contiguous batch vector under vmap
        x = self._predict(tuple(xt[i] for i in range(d)))  # the estimates and P per entry
        if self.steady:
            e = q - x[0]
            x = tuple(x[i] + self.K[i] * e for i in range(d))
            return KalmanState(jnp.moveaxis(jnp.stack(x), 0, -1), None), self._estimate(x)
        # P̄ = F P Fᵀ + q Q₁, entry by entry: (F P)_ij = Σ_k F_ik P_kj, P̄_ij = Σ_l (F P)_il F_jl
        F, Q1 = transition(d, self.dt), white_noise_covariance(d, self.dt)
        Pt = jnp.moveaxis(state.P, (-2, -1), (0, 1))
        P = lambda i, j: Pt[min(i, j), max(i, j)]
        FP = {(i, j): _combination((F[i, k], P(k, j)) for k in range(i, d)) for i in range(d) for j in range(d)}
        Pb = {(i, j): _combination((F[j, l], FP[i, l]) for l in range(j, d)) + self.q * Q1[i, j] for i, j in _pairs(d)}
        Pb_ = lambda i, j: Pb[min(i, j), max(i, j)]
        # gain and update, H = e₀ᵀ: S = P̄₀₀ + r, K = P̄_{·0} / S
        S = Pb[0, 0] + self.r
        K = tuple(Pb_(i, 0) / S for i in range(d))
        e = q - x[0]
        x = tuple(x[i] + K[i] * e for i in range(d))
        # Joseph form (I − K H) P̄ (I − K H)ᵀ + r K Kᵀ with I − K H = I − K e₀ᵀ, in two halves as the
        # matrix product does them: M = (I − K H) P̄, then M (I − K H)ᵀ; the upper triangle only
        M = {
            (i, j): (1.0 - K[0]) * Pb_(0, j) if i == 0 else Pb_(i, j) - K[i] * Pb_(0, j)
            for i in range(d)
            for j in range(d)
        }
        new = {
            (i, j): (M[i, 0] * (1.0 - K[0]) if j == 0 else M[i, j] - M[i, 0] * K[j]) + self.r * K[i] * K[j]
            for i, j in _pairs(d)
        }
        P = jnp.stack([jnp.stack([new[min(i, j), max(i, j)] for j in range(d)]) for i in range(d)])
        P = jnp.moveaxis(P, (0, 1), (-2, -1))
        return KalmanState(jnp.moveaxis(jnp.stack(x), 0, -1), P), self._estimate(x)

    def _estimate(self, x):
        return Estimate(x[0], x[1], x[2] if self.order == 3 else None)
