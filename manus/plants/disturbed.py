"""A plant with an unrecorded torque disturbance: a known sequence added to each command before
the actuator, so it acts on the plant but is not in the recorded command."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from manus.plants.simulator import Simulator
from manus.plants.stepper import Plant


class Disturbed(Plant):
    """`inner` with the disturbance `d[k]` (T, n) added to the command at tick k (the last row
    after the end). Zeros: no disturbance."""

    inner: Simulator
    d: Array

    @property
    def dt(self):
        return self.inner.dt

    @property
    def rate_hz(self):
        return self.inner.rate_hz

    @property
    def params(self):
        return self.inner.params

    def reset(self, key=None, q0=None, qd0=None):
        s, q = self.inner.reset(key, q0=q0, qd0=qd0)
        return (s, jnp.zeros((), jnp.int32)), q

    def measure(self, state):
        return self.inner.measure(state[0])

    def truth(self, state):
        return self.inner.truth(state[0])

    def step(self, state, command):
        s, k = state
        s, q = self.inner.step(s, command + self.d[jnp.minimum(k, self.d.shape[0] - 1)])
        return (s, k + 1), q
