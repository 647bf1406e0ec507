"""No crash on serial chains: `fit`, `diagnose` and `discover` on recordings of the double
pendulum's URDF (examples/dfki_double_pendulum) with random hidden effects, joints, amplitudes,
noise levels and lengths, plus degenerate ones (one joint that never moves, a few samples). Either
they answer, or they refuse with a `ManusError` whose message says what is wrong (not a Python
error passed on); any other exception fails the test with its trace."""

import pathlib

import jax.numpy as jnp
import numpy as np
import pytest

from manus.adaptive import diagnose, discover, fit
from manus.plants import Model, Serial, Simulator
from manus.plants.references import MultiSine
from manus.plants.serial_sim import record
from tests.adaptive.test_no_crash import answers

URDF = pathlib.Path(__file__).resolve().parents[2] / "examples" / "dfki_double_pendulum" / "double_pendulum_a0.urdf"
SEED = 11
HIDDEN = ("offset", "spring", "asymmetry", "stribeck", "cogging")  # per-joint effects on top of rigid,viscous,coulomb
CASES = len(HIDDEN)  # each hidden effect once, on a random joint at a random amplitude
SECONDS = 3.0


@pytest.fixture(scope="module")
def chain():
    return Serial.from_urdf(URDF)


def _case(chain, index: int):
    rng = np.random.default_rng([SEED, index])
    hidden = HIDDEN[index % len(HIDDEN)]
    joint = int(rng.integers(chain.n_joints))
    model = Model(chain, f"rigid,viscous,coulomb,{hidden}")
    params = model.defaults()
    scale = 10 ** rng.uniform(-2, 0)
    for k in Model(chain, hidden).names:
        if k[-1].isdigit():
            params[k] = params[k] * scale if int(k[-1]) == joint + 1 else 0.0
    sim = Simulator(model, params, substeps=4, actuator=None)
    rec = record(sim, MultiSine(jnp.zeros(chain.n_joints), 0.8, seed=index), SECONDS)
    rec.qd, rec.extra = None, {}
    rec = rec.window(0, int(rng.uniform(1.5, SECONDS) * 1000))
    noise = rng.uniform(0, 0.3)
    rec.tau = rec.tau + rng.standard_normal(rec.tau.shape) * noise * np.sqrt(np.mean(rec.tau**2, axis=0))
    return rec, f"case {index}: {hidden} x{scale:.3g} on joint {joint + 1}, {len(rec)} samples, noise {noise:.2f}"


@pytest.mark.parametrize("index", range(CASES))
def test_no_crash_on_a_serial_chain(chain, index):
    rec, what = _case(chain, index)
    start = "rigid,viscous,coulomb"
    answers(what, (("diagnose", lambda: diagnose(rec, start)), ("discover", lambda: discover(rec, start, max_steps=1))))


def test_degenerate_serial_recordings(chain):
    rec, what = _case(chain, 0)
    still = rec.window(0, len(rec))
    still.q = np.c_[still.q[:, 0], np.full(len(still), still.q[0, 1])]  # the elbow never moves
    for name, r in (("the elbow never moves", still), ("40 samples", rec.window(0, 40))):
        answers(
            f"{what}, {name}",
            (
                ("fit", lambda r=r: fit(r, "rigid,viscous,coulomb")),
                ("diagnose", lambda r=r: diagnose(r, "rigid,viscous,coulomb")),
            ),
        )
