"""Impedance (PD) control, thesis eq. 1.3, in joint space:

    τ = K (q_d − q) + B (q̇_d − v̂)

with v̂ from a velocity estimator (default: the thesis's filtered first difference). At a fixed
set point (q̇_d = 0) this is the thesis's τ = k(x_d − x) − b_c v̂. The command is clipped to
`limit` (the D/A's ±22.2 N·m by default).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from manus.estimators.base import Estimator, FilteredFirstDifference
from manus.plants.stepper import Controller, RefSample


class Impedance(Controller):
    stiffness: Array  # K (n,) [N·m/rad or N/m]
    damping: Array  # B (n,) [N·m·s/rad or N·s/m]
    estimator: Estimator = FilteredFirstDifference()
    limit: float = 22.2

    def __init__(self, stiffness=30.0, damping=1.0, estimator: Estimator | None = None, limit=22.2, n_joints=2):
        self.stiffness = jnp.broadcast_to(jnp.asarray(stiffness, float), (n_joints,))
        self.damping = jnp.broadcast_to(jnp.asarray(damping, float), (n_joints,))
        self.estimator = FilteredFirstDifference() if estimator is None else estimator
        self.limit = limit

    def init(self, q0):
        return self.estimator.init(q0), jnp.zeros_like(jnp.asarray(q0, float))

    def step(self, state, q, ref: RefSample):
        est_state, tau_prev = state
        est_state, est = self.estimator.step(est_state, q, tau_prev)
        tau = self.stiffness * (ref.q - q) + self.damping * (ref.qd - est.qd)
        tau = jnp.clip(tau, -self.limit, self.limit)
        return (est_state, tau), tau
