"""Luenberger observers, kinematic (`luenberger`) and model-based (`luenberger_model`).

Per joint, the state (q̂, q̂̇) is predicted over one period T at an acceleration a and corrected
by the prediction error of the measured position y (the "current estimator" form, which uses the
sample just taken):

    q̄ = q̂ + T q̂̇ + ½ T² a,   v̄ = q̂̇ + T a,   e = y − q̄
    q̂ ← q̄ + l₁ e,   q̂̇ ← v̄ + l₂ e

a = 0 for the kinematic observer (a double integrator); the model-based one takes a from the plant
model and the commanded torque (`manus.estimators.dynamics`), so that it follows accelerations
without the lag a kinematic observer needs to see them.

Gains by pole placement: the error of the kinematic observer evolves as e ← (I − L H) F e, whose
characteristic polynomial is z² − (2 − l₁ − T l₂) z + (1 − l₁). Both poles go to
z = exp(−ω T), a critically damped pair at the bandwidth ω [rad/s] (the knob):

    l₁ = 1 − z²,   l₂ = (1 − z)² / T

The model-based observer uses the same gains; its error poles move by the model's own dynamics
(T ∂a/∂(q, q̇), small against ω for a rigid arm). Default ω: the velocity carries the
quantization noise of the thesis's filtered first difference (`manus.estimators.linear`).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array

from manus.estimators.base import Estimate
from manus.estimators.dynamics import ModelBased, ModelDynamics
from manus.estimators.kalman import transition
from manus.estimators.linear import equal_noise_bandwidth


def gains(bandwidth: float, dt: float) -> np.ndarray:
    """(l₁, l₂) placing both error poles at exp(−ω T)."""
    z = np.exp(-bandwidth * dt)
    return np.array([1 - z * z, (1 - z) ** 2 / dt])


@functools.cache
def default_bandwidth(dt: float) -> float:
    """ω [rad/s] at which the observer's velocity noise equals the thesis filter's."""

    def design(w):
        L = gains(w, dt)
        return (np.eye(2) - np.outer(L, [1.0, 0.0])) @ transition(2, dt), L

    return equal_noise_bandwidth(design, dt)


class LuenbergerState(NamedTuple):
    q: Array  # position estimate (n,)
    qd: Array  # velocity estimate (n,)
    theta: Array | None  # model parameters (P,) (model-based only)
    commands: Array | None  # commands not yet acting (delay, n) (model-based with a delay only)


class Luenberger(ModelBased):
    """The observer of the module docstring; `dynamics=None` makes it kinematic.

    Build a model-based one with `Luenberger(dt, dynamics=ModelDynamics(model, dt), theta0=θ)`
    (or `manus.estimators.make("luenberger_model", model=..., params=...)`).
    """

    dt: float = eqx.field(static=True)
    bandwidth: Array  # ω [rad/s]
    gains: Array  # (l₁, l₂)
    dynamics: ModelDynamics | None
    theta0: Array | None

    def __init__(
        self, dt: float = 1e-3, bandwidth: float | None = None, dynamics: ModelDynamics | None = None, theta0=None
    ):
        self.dt = float(dt)
        w = default_bandwidth(self.dt) if bandwidth is None else float(bandwidth)
        if not 0 < w * self.dt < 20:
            raise ValueError(f"bandwidth must be positive and below ~20/T, got {w:g} rad/s")
        self.bandwidth = jnp.asarray(w)
        self.gains = jnp.asarray(gains(w, self.dt))
        self.dynamics = dynamics
        self.theta0 = None if dynamics is None else dynamics.theta(theta0)

    def init(self, q0):
        q0 = jnp.asarray(q0, float)
        if self.dynamics is None:
            return LuenbergerState(q0, jnp.zeros_like(q0), None, None)
        return LuenbergerState(q0, jnp.zeros_like(q0), self.theta0, self.dynamics.commands(q0.shape[-1]))

    def step(self, state, q, tau=None):
        if self.dynamics is None:
            q_bar, v_bar, a, commands = state.q + self.dt * state.qd, state.qd, None, None
        else:
            acting, commands = self.dynamics.acting(state.commands, tau, q.shape[-1])
            q_bar, v_bar, a = self.dynamics.predict(state.q, state.qd, acting, state.theta, self.dt)
        l1, l2 = self.gains
        e = q - q_bar
        new = LuenbergerState(q_bar + l1 * e, v_bar + l2 * e, state.theta, commands)
        return new, Estimate(new.q, new.qd, a)
