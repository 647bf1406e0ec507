"""The model-based Kalman filter (`kalman_model`): an extended Kalman filter on (q, q̇) of all
joints together, predicting with the plant model and the commanded torque.

State x = (q₁..qₙ, q̇₁..q̇ₙ). Over one period T, at the model's acceleration
a = H(q)⁻¹(τ − τ_model(q, q̇, 0; θ)) (`manus.estimators.dynamics`, θ in the state):

    x̄ = f(x) = (q + T q̇ + ½T² a, q̇ + T a),   F = ∂f/∂x (forward-mode, exact)
    P̄ = F P Fᵀ + q Q₁ ⊗ Iₙ,   Q₁ = [[T³/3, T²/2], [T²/2, T]]

Q is the covariance of a white acceleration disturbance of density `q` [position²/s³] on each
joint: everything the model misses (unmodelled effects, wrong parameters, the human's hand). The
measurement is y = q + v, E[v vᵀ] = R Iₙ, R = Δ²/12; the update is in Joseph form. The filter
starts from the steady-state covariance of the constant-velocity filter with the same q and R.

With a perfect model `q` can be small (the filter then averages the quantization noise over a
long window and still has no lag); with a poor one it must grow towards the kinematic filter's.
The default is the kinematic constant-velocity filter's (equal noise to the thesis's estimator).

Parameters: `with_params(state, θ)` (pure) replaces θ, e.g. with an adaptive controller's
current estimates every tick.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from manus.estimators.base import Estimate
from manus.estimators.dynamics import ModelBased, ModelDynamics
from manus.estimators.kalman import bandwidth_noise, default_bandwidth, steady_state, white_noise_covariance
from manus.estimators.linear import quantization_variance


def _inverse(S: Array) -> Array:
    """S⁻¹ of the small symmetric innovation covariance; closed form for one and two joints (a
    LAPACK call per step would cost more than the whole filter)."""
    n = S.shape[0]
    if n == 1:
        return 1.0 / S
    if n == 2:
        return jnp.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / (S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0])
    return jnp.linalg.inv(S)


class ModelKalmanState(NamedTuple):
    x: Array  # (q, q̇) estimates (2n,)
    P: Array  # posterior covariance (2n, 2n)
    theta: Array  # model parameters (P,)
    commands: Array | None  # commands not yet acting (delay, n); None without a delay


class ModelKalman(ModelBased):
    """The extended Kalman filter of the module docstring. `q` is the acceleration-disturbance
    density (the knob), `r` = Δ²/12 the measurement variance, `theta0` the initial parameters
    (a vector in `model.names` order or a dict; default: the model's defaults)."""

    dt: float = eqx.field(static=True)
    dynamics: ModelDynamics
    q: Array
    r: Array
    Q1: Array  # Q / q (2n, 2n)
    P0: Array  # (2n, 2n)
    theta0: Array

    def __init__(
        self,
        dynamics: ModelDynamics,
        dt: float = 1e-3,
        q: float | None = None,
        r: float = quantization_variance(),
        theta0=None,
    ):
        self.dt = float(dt)
        q = bandwidth_noise(2, self.dt, r, default_bandwidth(2, self.dt)) if q is None else float(q)
        if not (q > 0 and r > 0):
            raise ValueError(f"process noise q and measurement variance r must be positive, got {q:g}, {r:g}")
        n = dynamics.model.n_joints
        self.dynamics = dynamics
        self.q, self.r = jnp.asarray(q), jnp.asarray(float(r))
        self.Q1 = jnp.asarray(np.kron(white_noise_covariance(2, self.dt), np.eye(n)))
        self.P0 = jnp.asarray(np.kron(steady_state(2, self.dt, q, r)[0], np.eye(n)))
        self.theta0 = dynamics.theta(theta0)

    def init(self, q0):
        q0 = jnp.asarray(q0, float)
        n = self.dynamics.model.n_joints
        if q0.shape != (n,):
            raise ValueError(f"the estimator's model has {n} joint(s), the first measurement {q0.shape}")
        return ModelKalmanState(jnp.concatenate([q0, jnp.zeros(n)]), self.P0, self.theta0, self.dynamics.commands(n))

    def step(self, state, q, tau=None):
        n = q.shape[-1]
        acting, commands = self.dynamics.acting(state.commands, tau, n)

        def f(x):
            q_bar, v_bar, a = self.dynamics.predict(x[:n], x[n:], acting, state.theta, self.dt)
            y = jnp.concatenate([q_bar, v_bar])
            return y, (y, a)

        F, (x_bar, a) = jax.jacfwd(f, has_aux=True)(state.x)
        P = F @ state.P @ F.T + self.q * self.Q1
        S = P[:n, :n] + self.r * jnp.eye(n)
        K = P[:, :n] @ _inverse(S)  # P̄ Hᵀ S⁻¹, (2n, n)
        x = x_bar + K @ (q - x_bar[:n])
        IKH = jnp.eye(2 * n).at[:, :n].add(-K)
        P = IKH @ P @ IKH.T + self.r * K @ K.T
        return ModelKalmanState(x, P, state.theta, commands), Estimate(x[:n], x[n:], a)
