"""A disturbed plant: the disturbance acts on the plant as a command would, and is not in the
recorded command."""

import jax.numpy as jnp
import numpy as np
from jax import Array

from manus.plants import Axis, Model, Simulator
from manus.plants.closed_loop import simulate
from manus.plants.disturbed import Disturbed
from manus.plants.references import Hold
from manus.plants.stepper import Controller


class Play(Controller):
    """The torque `u[k]` at tick k, open loop."""

    u: Array

    def init(self, q0):
        return jnp.zeros((), jnp.int32)

    def step(self, state, q, ref):
        return state + 1, self.u[state]


def test_a_disturbance_acts_as_the_same_command_would_and_is_not_recorded():
    rng = np.random.default_rng(0)
    plant = Simulator(Model(Axis(), "rigid,viscous"), {"M1": 1.0, "b1": 0.5}, actuator=None, encoder=None)
    steps = 300
    u, d = rng.normal(size=(steps, 1)), 0.5 * rng.normal(size=(steps, 1))
    seconds = steps * plant.dt
    disturbed = simulate(Disturbed(plant, jnp.asarray(d)), Play(jnp.asarray(u)), Hold([0.0]), seconds)
    commanded = simulate(plant, Play(jnp.asarray(u + d)), Hold([0.0]), seconds)
    np.testing.assert_allclose(disturbed.q_true, commanded.q_true, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(disturbed.tau, u)
    assert np.abs(disturbed.q_true - simulate(plant, Play(jnp.asarray(u)), Hold([0.0]), seconds).q_true).max() > 1e-4
