"""Output-error identification (`manus.adaptive.identify.output_error`, `--method oe`) against the
truth a pendulum was simulated with: where a coarse encoder, a low rate and a chattering
bang-bang torque far below gravity's collapse least squares (the real pendulum of issue 32),
OE recovers the inertia and m g l and `auto` chooses it, saying why; on a clean recording OE
and LS agree within their standard deviations and `auto` is unchanged."""

import contextlib
import io
import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.adaptive import fit
from manus.plants import Model, Simulator
from manus.plants.closed_loop import simulate
from manus.plants.recording import from_trajectory, write
from manus.plants.references import Hold
from manus.plants.simulator import Encoder
from manus.plants.stepper import Controller
from manus.plants.structures import Axis
from manus.runs.cli import main

MODEL = "rigid,viscous,coulomb,gravity"
# a pendulum hanging at q = 0: J = 0.2 kg m², m g l = 2 N·m, light friction
TRUTH = {"M1": 0.2, "b1": 0.01, "Fc1": 0.02, "gc1": 0.0, "gs1": 2.0}


class Pump(Controller):
    """Bang-bang energy pumping: ±u as the velocity's sign while the swing's energy is below the
    target (amplitude `amp`), −u against it above; the velocity a first difference of the
    encoder low-passed at `velocity_hz`. Near the target and at each reversal the sign chatters."""

    u: float
    amp: float
    velocity_hz: float
    dt: float

    def init(self, q0):
        q0 = jnp.asarray(q0, float)
        return q0, jnp.zeros_like(q0)

    def step(self, state, q, ref):
        q_prev, v = state
        v = v + (1 - math.exp(-2 * math.pi * self.velocity_hz * self.dt)) * ((q - q_prev) / self.dt - v)
        energy = 0.5 * TRUTH["M1"] * v**2 + TRUTH["gs1"] * (1 - jnp.cos(q))
        target = TRUTH["gs1"] * (1 - math.cos(self.amp))
        return (q, v), self.u * jnp.sign(v) * jnp.sign(target - energy)


def swing(rate: float, step: float, u: float, amp: float, seconds: float = 20.0, q0: float = 0.3):
    """The pendulum swung by `Pump` from `q0` [rad], recorded at `rate` with an encoder of `step`."""
    plant = Simulator(
        Model(Axis(n_joints=1), MODEL),
        TRUTH,
        rate_hz=rate,
        actuator=None,
        encoder=Encoder(step=step),
        q0=jnp.array([q0]),
    )
    ctrl = Pump(u, amp, 40.0, 1 / rate)
    traj = simulate(plant, ctrl, Hold(np.array([q0])), seconds, key=jax.random.PRNGKey(0))
    rec = from_trajectory(traj, rate, "axis", 2 * math.pi / step, {"joints": "revolute"})
    rec.qd, rec.extra, rec.path = None, {}, f"<pendulum {rate:g} Hz, step {step:.2g}>"
    return rec


@pytest.fixture(scope="module")
def coarse():
    """200 Hz, a 0.0029 rad encoder step, a bang-bang torque of 0.04 N·m (2 % of gravity's peak)
    chattering at the swing's target: the motion band (29 Hz) is the chatter's, the cut-off is
    capped by the encoder's noise."""
    return swing(200.0, 0.0029, 0.04, 0.5)


def test_coarse_encoder_least_squares_collapses_output_error_recovers(coarse, tmp_path):
    ls = fit(coarse, MODEL, method="ls")
    assert ls.params["M1"] < 0.5 * TRUTH["M1"] and ls.params["gs1"] < 0.5 * TRUTH["gs1"]
    auto = fit(coarse, MODEL)
    assert auto.method == "oe" and "quantization noise" in auto.why and "M1" in auto.why
    for k in ("M1", "gs1"):
        assert auto.params[k] == pytest.approx(TRUTH[k], rel=0.25), k
    r = auto.report()
    assert r["method"] == "oe" and r["method_why"] == auto.why
    oe = r["output_error"]
    assert oe["position_rel_error"] < 0.5 * oe["compared"]["position_rel_error"]  # LS's parameters simulate worse
    assert oe["position_rms"][0] < 0.5 * oe["encoder_step"]  # the simulation follows the recording within the grid
    # the command line: --method oe, the same numbers in its JSON
    path = write(coarse, tmp_path / "pendulum.csv")
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = main(["fit", str(path), "--model", MODEL, "--method", "oe", "--no-figures", "--json"])
    assert code == 0
    cli = json.loads(out.getvalue())
    assert cli["method"] == "oe" and cli["method_why"] == "output error (asked for)"
    assert cli["params"]["M1"]["value"] == pytest.approx(auto.params["M1"], rel=0.02)


def test_on_a_clean_recording_output_error_agrees_with_least_squares():
    """1 kHz, 2¹⁷ counts per revolution, a torque of 0.4 N·m: least squares is unbiased, `auto`
    does not choose OE, and OE's parameters agree with LS's within their combined standard
    deviations."""
    rec = swing(1000.0, 2 * math.pi / 2**17, 0.4, 1.0, seconds=10.0)
    ls, auto = fit(rec, MODEL, method="ls"), fit(rec, MODEL)
    assert auto.method != "oe"
    oe = fit(rec, MODEL, method="oe")
    for k in ("M1", "b1", "Fc1", "gs1"):
        assert abs(oe.params[k] - ls.params[k]) < 2 * math.hypot(oe.stds[k], ls.stds[k]), k
        assert oe.params[k] == pytest.approx(TRUTH[k], rel=0.05), k


def test_output_error_needs_a_model_with_inertia(coarse):
    from manus.plants.errors import ModelError

    with pytest.raises(ModelError, match="no inertia"):
        fit(coarse, "viscous,coulomb,gravity", method="oe")


def test_a_model_whose_simulation_leaves_the_motion_is_refused_by_name(coarse, monkeypatch):
    """Without gravity the swung pendulum cannot be simulated from the recorded command (the
    command is far smaller than gravity): output error refuses the model with a message naming
    why, never an internal error; and where the minimisation's linear algebra fails on a window
    whose simulation left the data, that failure is the same one-line refusal."""
    from manus.adaptive.identify import output_error as oe
    from manus.plants.errors import ModelError

    with pytest.raises(ModelError, match="simulat"):
        fit(coarse, "rigid,viscous", method="oe")

    def diverged(*args, **kwargs):
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(oe, "_minimise", diverged)
    with pytest.raises(ModelError, match="leaves the recorded motion within a window"):
        fit(coarse, MODEL, method="oe")
