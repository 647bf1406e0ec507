"""The calibration of `manus diagnose` (issue: "nothing missing: verdict null in at least 98 % of
recordings; each effect hidden at 5 % of the torque RMS: named in at least 90 %"), on a small
seeded subset of the calibration set (`manus.experiments.calibration`); the whole set is the benchmark
`manus bench diagnose --calibrate`. Every test here is named `test_calibration_*`:

    pytest tests/runs/test_calibration.py          # or: pytest -k calibration

A null recording must get a null verdict; a hidden effect must be named (on its joint when it was
hidden on one); the pendulum (errors in the variables: a 4096-count encoder at 200 Hz) must give
its inertia and gravity within 10 %.
"""

from typing import Any

import pytest

from manus.adaptive import diagnose, fit
from manus.experiments import calibration, judging, sizing

SEED = 20240607  # the subset's seeds: SEED + index
PENDULUM_SEED = 3
PENDULUM_TOLERANCE = 0.10  # relative, on the inertia M1 and the gravity term gs1

# nothing hidden, across the conditions (structure, rate, excitation, torque, hold)
NULLS = [
    dict(structure="arm", rate=1000, excitation="multisine", torque="exact", hold="stated"),
    dict(structure="axis", rate=1000, excitation="reaching", torque="white", hold="stated"),
    dict(structure="arm", rate=200, excitation="steps", torque="coloured", hold="not stated"),
    dict(structure="axis", rate=200, excitation="multisine", torque="exact", hold="not stated"),
    dict(structure="arm", rate=1000, excitation="reaching", torque="white", hold="not stated"),
    dict(structure="axis", rate=1000, excitation="steps", torque="coloured", hold="stated"),
]
# one per hidden effect, at an easy condition: the arm at 1 kHz under the multi-sine, exact
# torque, hold stated (compliance: under the open-loop steps, the only excitation that rings it)
EASY: dict[str, Any] = dict(structure="arm", rate=1000, excitation="multisine", torque="exact", hold="stated")
HIDDEN = calibration.hidden_effects()


def _easy(effect: str) -> dict:
    return {**EASY, "excitation": "steps"} if effect == "compliance" else EASY


def _verdict(d) -> str:
    v = d.verdict
    return "null" if v is None else f"{v.spec} on joint {v.joint}"


@pytest.mark.parametrize("index", range(len(NULLS)), ids=lambda i: "-".join(str(v) for v in NULLS[i].values()))
def test_calibration_nothing_missing_gives_a_null_verdict(index):
    c = calibration.case(SEED + index, None, **NULLS[index])
    d = diagnose(c.rec, c.start)
    assert d.verdict is None, f"{c.describe()}: false alarm, verdict {_verdict(d)}"


@pytest.mark.parametrize("effect", HIDDEN)
def test_calibration_a_hidden_effect_is_named(effect):
    c = calibration.case(SEED + 100 + HIDDEN.index(effect), effect, **_easy(effect))
    d = diagnose(c.rec, c.start)
    assert d.verdict is not None and d.verdict.effect == effect, (
        f"{c.describe()} ({c.condition}): verdict {_verdict(d)}"
    )
    if c.joint is not None:
        assert d.verdict.joint == c.joint, f"{c.describe()}: named on joint {d.verdict.joint}"


# where a simpler rival was within one standard error (a delay, which with viscous friction in the
# model mimics an inertia: b·q̇(t + d) ≈ b·q̇ + b·d·q̈), an offset came before the spring that
# brings it, or an offset fitted the held-out blocks a little better than a viscous asymmetry
# (|q̇| has a mean): the calibration's cases (seeds 0, 5) that named the rival before the
# encompassing rule. Since the rests left the cut-off's low-pass, the inertia (seed 157331075) and
# the spring (seed 2020960705) are named without it; of the named hidden effects of seeds 0 and 5,
# this asymmetry is the one that still needs it.
ENCOMPASSED = [
    (
        557679455,
        "asymmetry",
        dict(structure="axis", rate=200, excitation="multisine", torque="coloured", hold="not stated"),
    ),
]


@pytest.mark.parametrize("seed,effect,condition", ENCOMPASSED, ids=[e for _, e, _ in ENCOMPASSED])
def test_calibration_the_verdict_encompasses_its_simpler_rival(seed, effect, condition):
    """The hidden effect adds a significant share of the torque on top of the simpler rival, and
    the rival nothing on top of it: the hidden effect is named, its note says why."""
    c = calibration.case(seed, effect, **condition)
    d = diagnose(c.rec, c.start)
    assert d.verdict is not None and d.verdict.effect == effect, f"{c.describe()}: verdict {_verdict(d)}"
    assert "accounts for what" in d.verdict.note and "in its place" in d.verdict.note, d.verdict.note


def test_calibration_pendulum_inertia_and_gravity_within_ten_percent():
    c = calibration.pendulum(PENDULUM_SEED)
    assert 1.0 <= c.condition["swing_rad"] <= 2.2 and c.condition["drive_over_gravity"] < 0.25, c.condition
    f = fit(c.rec, c.start)
    for name in ("M1", "gs1"):
        assert f.params[name] == pytest.approx(c.truth[name], rel=PENDULUM_TOLERANCE), (name, f.params, c.truth)


def _swing(seconds=6.0, rate=200, amplitude=0.3):
    """The arm swinging ±`amplitude` rad about its workspace centre (both joints), a recorded
    torque of RMS 1 N·m: what `sizing.distinct` needs of a trajectory."""
    from types import SimpleNamespace

    import numpy as np

    t = np.arange(int(seconds * rate)) / rate
    w = 2 * np.pi * np.array([0.5, 0.7])
    q = np.asarray(calibration.ARM.centre) + amplitude * np.sin(w * t[:, None])
    qd = amplitude * w * np.cos(w * t[:, None])
    return SimpleNamespace(q_true=q, qd_true=qd, tau=np.ones_like(q)), 1.0 / rate


def test_calibration_distinct_share_of_a_hidden_effect():
    """A tilted plane on a ±0.3 rad swing is nearly a constant plus a spring: what sets it apart
    is its curvature, which a least-squares line in q leaves (numpy, per joint): the distinct
    share is that (the spring with its preload is the closest rival). A 39/rev cogging has no
    rival: its distinct share is nearly all of it."""
    import numpy as np

    from manus.plants.effects import Cogging, Gravity

    traj, dt = _swing()
    g = {"gc1": 0.03, "gs1": -0.01, "gc2": 0.02, "gs2": 0.015}
    got = sizing.distinct(calibration.ARM, Gravity(), g, "", traj, dt)
    q = traj.q_true
    torque = np.stack([g[f"gc{i + 1}"] * np.cos(q[:, i]) + g[f"gs{i + 1}"] * np.sin(q[:, i]) for i in range(2)], 1)
    left = [torque[:, i] - np.polyval(np.polyfit(q[:, i], torque[:, i], 1), q[:, i]) for i in range(2)]
    curvature = float(np.sqrt(np.mean(np.square(left))))
    whole = float(np.sqrt(np.mean(torque**2)))
    assert got == pytest.approx(curvature, rel=1e-4) and curvature < 0.05 * whole  # the spring's line is the best rival
    c = {"A1": 0.01, "B1": 0.005, "A2": 0.008, "B2": -0.004}
    cogging = sizing.distinct(calibration.ARM, Cogging(order=39.0), c, "", traj, dt)
    size = float(
        np.sqrt(np.mean(sizing.effect_torque(calibration.ARM, Cogging(order=39.0), c, q, traj.qd_true, 0 * q) ** 2))
    )
    assert cogging == pytest.approx(size, rel=0.2)


def test_calibration_bench_runs_in_worker_processes(calibrate_args):
    """`manus bench diagnose --calibrate` over two spawned workers: every recording comes back, in
    the plan's order, with its outcome, its candidates' p-values and the rates' JSON keys."""
    from manus.runs.bench import diagnose as bench

    args = calibrate_args(recordings=1, effects="offset", seed=3, alpha=None, blocks=None, jobs=2)
    r = bench.calibrate(args)
    assert [x["hidden"] for x in r["results"]] == [None, "offset"]
    assert all(x["outcome"] in ("quiet", "false alarm", "named", "reading", "missed", "wrong") for x in r["results"]), (
        r["results"]
    )
    from manus.adaptive import ALPHA

    assert r["crashes"] == {} and r["jobs"] == 2 and r["alpha"] == pytest.approx(ALPHA)
    assert all("p_value" in c for x in r["results"] for c in x["candidates"])
    s = r["calibration"]
    assert {"false_alarm", "detection", "detection_where_distinct", "per_effect", "per_condition"} <= set(s)
    assert "distinct_fraction" in r["results"][1]["condition"]
    assert "named where distinct" in bench.render_calibration(r)
    # the workers compute as this process does (float64: they once simulated and diagnosed in
    # JAX's default float32, which `manus` never runs in)
    here = [judging.judge(x["seed"], x["hidden"]) for x in r["results"]]
    key = lambda x: [(c["spec"], c["p_value"], c["cv_error_reduction"]) for c in x["candidates"]]
    assert [key(x) for x in r["results"]] == [key(x) for x in here]


def test_calibration_at_a_rate_of_the_users_choice():
    """`--rates`: a case drawn at another rate is sampled at it, lasts 12 s at 1 kHz and faster
    (20 s below), and a hidden delay there is sized like every effect, by what it changes in the
    torque (5 % of its RMS, within the set's tolerance); a rate that is no whole number of Hz, or
    outside 100 Hz–20 kHz, is refused by name."""
    import numpy as np

    c = calibration.case(
        SEED, "delay", rates=(2000,), structure="axis", excitation="reaching", torque="exact", hold="stated"
    )
    assert c.condition["rate"] == 2000 and np.median(np.diff(c.rec.t)) == pytest.approx(5e-4)
    assert len(c.rec) == pytest.approx(12.0 * 2000, abs=2) and c.condition["delay_ms"] > 1.0
    assert c.condition["hidden_fraction"][0] == pytest.approx(calibration.AMPLITUDE, rel=calibration.TOLERANCE)
    assert calibration.seconds_at(500) == 20.0 and calibration.seconds_at(1000) == 12.0
    assert {calibration.draw_condition(SEED + i, None, rates=(500, 2000))["rate"] for i in range(20)} == {500, 2000}
    for bad in ((50,), (500.5,), ()):
        with pytest.raises(ValueError, match="whole numbers of Hz"):
            calibration.check_rates(bad)


def test_calibration_a_mode_at_2khz_is_found_and_one_the_encoder_cannot_resolve_is_said_so():
    """The arm at 2 kHz (a 131072-count encoder): θ̈ from twice-differenced positions carries the
    quantization's noise, growing as 1/dt², and a 379 Hz shaft mode moves the motor little more
    than a count's worth there: the torque→acceleration response is coherent only around the
    mode (γ² ≈ 0.1-0.2), enough to find it at its frequency and see its peak (whether the held-out
    blocks, each searched again on the others, confirm it at the family's level is marginal:
    p ≈ 0.01 on this recording, not proposed). The same motion read by an encoder 8 times coarser
    (16384 counts) leaves no bin of the band coherent: no mode is proposed, and the notes (or
    the candidate) say why."""
    import numpy as np

    c = calibration.case(2068263202, "compliance", rates=(2000,))
    assert c.condition["structure"] == "arm" and c.condition["f_hz"] == pytest.approx(379.0, abs=0.1)
    d = diagnose(c.rec, c.start)
    assert d.verdict is None or d.verdict.effect == "compliance", _verdict(d)
    comp = next(x for x in d.candidates if x.effect == "compliance")
    assert comp.detail["f_hz"] == pytest.approx(379.0, rel=0.02) and comp.detail["resonance_peak"]
    step = 2 * np.pi / 16384
    c.rec.q = np.round(c.rec.q / step) * step
    c.rec.meta["counts_per_rev"] = "16384"
    d = diagnose(c.rec, c.start)
    assert d.verdict is None or d.verdict.effect != "compliance"
    comp = next((x for x in d.candidates if x.effect == "compliance"), None)
    if comp is None:  # no mode fits at all: the notes say why
        said = [n for n in d.notes if n.startswith("compliance:")]
        assert said and "cannot show a structural mode" in said[0] and "coherence below" in said[0], d.notes
    else:
        assert not comp.proposable and comp.detail["coherent_to_hz"] < 100.0
        assert "coherent only up to" in comp.note and "cannot show" in comp.note, comp.note


def test_calibration_at_another_amplitude():
    """`--amplitude`: the hidden effect's torque RMS is that share of the recorded torque's
    (within the set's re-scaling tolerance); outside (0, 1) it is refused."""
    c = calibration.case(SEED + 100, "offset", amplitude=0.1, **EASY)
    got = [g for g in c.condition["hidden_fraction"] if g > 0]
    assert got and all(g == pytest.approx(0.1, rel=calibration.TOLERANCE) for g in got), c.condition
    with pytest.raises(ValueError, match="between 0 and 1"):
        calibration.case(SEED + 100, "offset", amplitude=1.5, **EASY)


def test_calibration_with_samples_lost(calibrate_args):
    """`--lost`: a recording that lost 1 % of its samples at random (a loop that misses packets)
    is diagnosed as the whole one: a hidden offset named on its joint, nothing on a null, and the
    count lost in the condition; a fraction outside [0, 0.5) is refused by name."""
    from manus.plants.errors import ManusError
    from manus.runs.bench import diagnose as bench

    hidden = judging.judge(SEED + 100 + HIDDEN.index("offset"), "offset", lost=0.01)
    rate = hidden["condition"]["rate"]
    expected = 0.01 * rate * calibration.seconds_at(rate)  # 1 % of the samples, binomial
    lost = hidden["condition"]["lost_samples"]
    assert hidden["outcome"] == "named" and abs(lost - expected) < 4 * expected**0.5, hidden.get("condition")
    null = judging.judge(SEED, None, lost=0.01)
    assert null["outcome"] == "quiet" and null["condition"]["lost_samples"] > 0, null.get("verdict_spec")
    with pytest.raises(ManusError, match=r"--lost must lie in \[0, 0.5\) \(got 0.7\)"):
        bench.calibrate(calibrate_args(recordings=1, effects="none", seed=3, alpha=None, blocks=None, jobs=1, lost=0.7))


def test_a_delay_is_sized_by_what_it_changes():
    """`delay_change` against its closed form: a sinusoid of angular frequency ω read d late
    changes by 2|sin(ωd/2)| of its RMS; `size_delay` returns the shortest delay on its 0.1 ms grid
    reaching the asked share (2 arcsin(a/2)/ω), never under 1 ms: a torque step changes by far more
    than 5 % in a millisecond, and 1 ms is what the set hides then."""
    import numpy as np

    rate, w = 1000.0, 2 * np.pi * 3.0
    t = np.arange(20000) / rate
    tau = np.c_[np.sin(w * t), 2 * np.sin(w * t + 1.0)]
    got = sizing.delay_change(tau, 4.3e-3, rate)
    assert got == pytest.approx(2 * np.sin(w * 4.3e-3 / 2), rel=1e-3)  # each joint, and both together
    want = 2 * np.arcsin(0.05 / 2) / w
    d = sizing.size_delay(tau, rate, 0.05)
    assert want <= d < want + 1e-4 + 1e-9
    steps = np.repeat([[0.0], [1.0], [-1.0], [0.5]], 500, axis=0)
    assert sizing.size_delay(steps, rate, 0.05) == sizing.DELAY_MIN


def test_robots_are_the_chain_sets_and_refused_by_name(calibrate_args):
    """`--robots`: only with `--simulator chain`, only robots the chain set has; each refused in
    one line before any recording is simulated."""
    from manus.plants.errors import ManusError
    from manus.runs.bench import diagnose as bench

    with pytest.raises(ManusError, match=r"--robots: unknown robot\(s\) kuka: the chain set has panda, ur5, xarm7"):
        bench.calibrate(calibrate_args(recordings=1, effects="none", simulator="chain", robots="kuka", jobs=1))
    with pytest.raises(ManusError, match="--robots: only with --simulator chain"):
        bench.calibrate(calibrate_args(recordings=1, effects="none", robots="xarm7", jobs=1))
