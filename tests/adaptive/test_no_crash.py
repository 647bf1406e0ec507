"""No crash: `diagnose` and `discover` over many random combinations of hidden effects, joints,
amplitudes, rates, noise levels, lengths and structures, plus degenerate recordings (a joint that
never moves, 30 samples, a constant torque, nothing moving at all, a zero torque). `discover` runs
on every case (it diagnoses the start and each step), `diagnose` itself on the degenerate ones and
on every third random one (the cost of a diagnosis bounds the size). Either they answer, or they
refuse with a `ManusError` whose message says what is wrong; any other exception fails the test
with its trace.

    pytest tests/adaptive/test_no_crash.py
"""

import re
import traceback

import numpy as np
import pytest

from manus.adaptive import diagnose, discover
from manus.experiments import calibration, sizing
from manus.plants.effects import VOCABULARY, Compliance, Delay, Model
from manus.plants.errors import ManusError
from manus.plants.recording import from_trajectory

SEED = 7  # the fuzz's seeds: SEED + case index
CASES = 16  # random combinations
SIM_SECONDS = 8.0  # every run is simulated this long (one compilation per set-up), then cut to 3–8 s
RATES = (200, 500, 1000)
DELAY_MS = 2.0  # a hidden delay (one value: each is a compilation)
MAX_STEPS = 1  # discover's cap (each step is a diagnosis: at most two per run)
DIAGNOSE_EVERY = 3  # diagnose itself on every third random case (discover runs it on all)
NOISE = (0.0, 0.3)  # white noise on the recorded torque, fraction of its RMS
AMPLITUDE = (-2.0, 1.0)  # log10 of the factor on a hidden effect's default parameters

# messages of Python's own exceptions: a ManusError that only passes one on is a crash in disguise
PYTHON_TEXT = re.compile(
    r"object has no attribute|out of bounds|index out of range|division by zero|unsupported operand|"
    r"not subscriptable|could not be broadcast|cannot reshape|not aligned|Singular matrix|"
    r"^\w+(Error|Exception)\b|Traceback|NoneType|takes \d+ positional|unexpected keyword|must be real number|"
    r"invalid value encountered|zero-size array"
)


def _combination(index: int) -> dict:
    rng = np.random.default_rng([SEED, index])
    setup = calibration.SETUPS[str(rng.choice(calibration.STRUCTURES))]
    rate = int(rng.choice(RATES))
    excitation = "steps" if rate == 1000 and rng.random() < 0.3 else "multisine"
    pool = [
        e
        for e in calibration.hidden_effects()
        if sizing.applies(e, setup) and (e != "compliance" or excitation == "steps")
    ]
    hidden = sorted(rng.choice(pool, size=int(rng.integers(1, 4)), replace=False).tolist(), key=pool.index)
    return {
        "setup": setup,
        "rate": rate,
        "excitation": excitation,
        "hidden": hidden,
        "joint": [None, *range(1, setup.n + 1)][int(rng.integers(setup.n + 1))],
        "amplitude": float(10 ** rng.uniform(*AMPLITUDE)),
        "noise": float(rng.uniform(*NOISE)),
        "seconds": float(rng.uniform(3.0, SIM_SECONDS)),
        "hold": bool(rng.random() < 0.5),
        "seed": int(rng.integers(2**31)),
    }


def _recording(c: dict):
    setup = c["setup"]
    params = dict(setup.nominal)
    extra = []
    for name in c["hidden"]:
        if name == "delay":
            extra.append(Delay(seconds=DELAY_MS * 1e-3))
            continue
        if name == "compliance":
            extra.append(Compliance(f_hz=0.2 * c["rate"], zeta=0.02))
            continue
        effect = VOCABULARY[name]()
        owner = sizing.parameter_joints(setup, effect)
        for k, v in Model(setup.structure, name).defaults().items():
            # the rigid effect is scaled as a whole (a plant needs a positive definite inertia)
            on = name == "rigid" or owner.get(k) is None or c["joint"] is None or owner[k] == c["joint"] - 1
            params[k] = setup.nominal.get(k, v) * c["amplitude"] if on else 0.0
    traj = calibration.simulate_case(setup, c["rate"], c["excitation"], params, tuple(extra), SIM_SECONDS, c["seed"])
    rec = from_trajectory(
        traj,
        c["rate"],
        "manus2" if setup.name == "arm" else "axis",
        131072 if setup.name == "arm" else None,
        setup.meta(),
    )
    rec.qd, rec.extra = None, {}
    rec = rec.window(0, int(c["seconds"] * c["rate"]))
    rng = np.random.default_rng(c["seed"])
    rec.tau = rec.tau + rng.standard_normal(rec.tau.shape) * c["noise"] * np.sqrt(np.mean(rec.tau**2, axis=0))
    if not c["hold"]:
        rec.meta.pop("command_hold", None)
    start = ",".join(e for e in calibration.NOMINAL if e not in c["hidden"]) or "rigid"
    return rec, start


def _run(rec, start: str, what: str, direct: bool = True) -> list[str]:
    """discover (and diagnose itself when `direct`); returns the ManusError messages (each checked),
    fails on anything else."""
    calls = (("diagnose", lambda: diagnose(rec, start)),) if direct else ()
    calls += (("discover", lambda: discover(rec, start, max_steps=MAX_STEPS)),)
    return answers(what, calls)


def answers(what: str, calls) -> list[str]:
    """Each (name, call): it answers (its `report()` too), or refuses with a `ManusError` whose
    message says what is wrong; returns those messages, fails the test on anything else."""
    refused = []
    for name, call in calls:
        try:
            out = call()
            out.report()
        except ManusError as e:
            message = str(e).strip()
            assert message, f"{what}: {name} raised {type(e).__name__} with an empty message"
            assert not PYTHON_TEXT.search(message), f"{what}: {name} refused with a bare Python error: {message!r}"
            refused.append(f"{name}: {message}")
        except Exception:
            pytest.fail(f"{what}: {name} crashed:\n{traceback.format_exc()}")
    return refused


@pytest.mark.parametrize("index", range(CASES))
def test_no_crash_random_combination(index):
    c = _combination(index)
    rec, start = _recording(c)
    what = (
        f"case {index} ({c['setup'].name} {c['rate']} Hz {c['excitation']} {c['seconds']:.1f} s, hidden "
        f"{'+'.join(c['hidden'])} x{c['amplitude']:.3g} on joint {c['joint'] or 'all'}, noise {c['noise']:.2f}, "
        f"hold {'stated' if c['hold'] else 'not stated'}, start {start})"
    )
    _run(rec, start, what, direct=index % DIAGNOSE_EVERY == 0)


@pytest.fixture(scope="module")
def arm():
    """A plain arm recording (nothing hidden) to break in the degenerate cases."""
    c = calibration.case(SEED, None, structure="arm", rate=1000, excitation="multisine", torque="exact", hold="stated")
    return c.rec


def _copy(rec, **changes):
    out = rec.window(0, len(rec))
    for k, v in changes.items():
        setattr(out, k, v)
    return out


DEGENERATE = {
    "a joint that never moves": lambda r: _copy(r, q=np.c_[r.q[:, 0], np.full(len(r), r.q[0, 1])]),
    "30 samples": lambda r: r.window(0, 30),
    "a constant torque": lambda r: _copy(r, tau=np.full_like(r.tau, 0.3)),
    "nothing moves": lambda r: _copy(r, q=np.repeat(r.q[:1], len(r), axis=0)),
    "a zero torque": lambda r: _copy(r, tau=np.zeros_like(r.tau)),
}


@pytest.mark.parametrize("name", list(DEGENERATE))
def test_no_crash_degenerate_recording(name, arm):
    rec = DEGENERATE[name](arm)
    for start in ("rigid,viscous,coulomb", "rigid"):
        _run(rec, start, f"degenerate: {name} (start {start})")
