"""Shared inputs of the estimator tests: a quantized two-joint signal, and a simulated recording of
the arm (131072 counts/rev, 1 kHz, human-like motion up to 5 Hz, then holding still)."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants.references import MultiSine, PositionReference

STEP = 2 * math.pi / 131072
DT = 1e-3


def quantized_motion(samples=300, seed=0):
    """(q, tau) (T, 2): smooth motion of a few Hz on the encoder grid, and torques."""
    rng = np.random.default_rng(seed)
    t = np.arange(samples) * DT
    f, ph = rng.uniform(0.5, 5, (3, 2)), rng.uniform(0, 2 * np.pi, (3, 2))
    q = np.array([0.464, 2.409]) + sum(0.03 * np.sin(2 * np.pi * f[i] * t[:, None] + ph[i]) for i in range(3))
    tau = 0.4 * np.sin(2 * np.pi * 1.7 * t[:, None] + np.array([0.0, 1.0]))
    return np.round(q / STEP) * STEP, tau


@pytest.fixture
def motion():
    return quantized_motion()


class MoveThenHold(PositionReference):
    """A multi-sine (human-like: 0.5–5 Hz) that fades out at `stop` seconds, then holds."""

    inner: MultiSine
    stop: float

    def position(self, t):
        x = jnp.clip((t - self.stop) / 0.4, 0.0, 1.0)
        fade = 1 - x * x * x * (10 - 15 * x + 6 * x * x)
        return self.inner.centre + fade * (self.inner.position(t) - self.inner.centre)


@pytest.fixture(scope="session")
def arm_recording(tmp_path_factory):
    """The thesis's arm (rigid, viscous, Coulomb, 1 ms delay) under stiff impedance control
    (K = 300 N·m/rad, B = 4 N·m·s/rad, the thesis's filtered first difference in the loop),
    3.5 s: 2.5 s of motion, then holding still. Written as a CSV recording with the truth."""
    from manus.adaptive.impedance import Impedance
    from manus.plants import Model, Simulator, recording
    from manus.plants.closed_loop import simulate
    from manus.plants.structures import Manus2

    plant = Simulator(Model(Manus2(), "rigid,viscous,coulomb,delay"))
    reference = MoveThenHold(MultiSine(amplitude=0.1, f_min=0.5, f_max=5.0, components=6, ramp=0.3), 2.5)
    traj = simulate(plant, Impedance(300.0, 4.0, n_joints=2), reference, 3.5)
    rec = recording.from_trajectory(traj, 1000.0, "manus2", 131072)
    path = recording.write(rec, tmp_path_factory.mktemp("arm") / "arm.csv")
    return recording.read(path)


@pytest.fixture(scope="session")
def arm_report(arm_recording):
    """`compare` of every estimator on the arm recording: (report, estimates)."""
    from manus.estimators.compare import compare

    return compare(arm_recording)
