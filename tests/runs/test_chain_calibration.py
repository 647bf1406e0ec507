"""A seeded subset of the chain calibration (`manus.experiments.chains`, `manus bench diagnose
--calibrate --simulator chain`): the independent engine's recording (pinocchio's ABA) is what
manus identifies; chains with nothing missing stay quiet, among them the UR5 with a differential
wrist (stated by its file's `# transmission:` line), smooth friction and a PC's log (repeated
rows, jittered stamps) read back through `read`; an effect of 3 % of ONE joint's torque,
far under 0.5 % of all the torque (0.1 % here), is named on its joint; a coupling of two joints
hidden in the truth is named with its joints and sign."""

import numpy as np
import pytest

from manus.experiments import chains
from manus.experiments.judging import _outcome, judge
from manus.plants.transmission import parse

pytest.importorskip("pinocchio")  # (example-robot-data comes with it)

# (seeds of `manus bench diagnose --calibrate --simulator chain --recordings 4 --effects coupling,smooth`)
NULLS = (
    779308542,  # the UR5 at 100 Hz open loop, exact torque: differential wrist, smooth friction, a PC's log
    821328062,  # the Panda at 100 Hz closed loop, exact torque, Coulomb friction, a clean log
)
HIDDEN = (
    (465539299, "offset"),  # the Panda at 200 Hz, open loop: an offset of 3 % of joint 7's torque
    (1523182615, "coupling"),  # the Panda at 1 kHz, open loop, exact torque: friction on q̇_? ± q̇_?
)


def test_the_conditions_keep_their_rules():
    """The robot, rate, loop and torque of a seed do not depend on the keys added after them; a
    differential wrist is the UR5's, with smooth friction; a Stribeck hump has Coulomb friction on
    joints."""
    for seed in range(40):
        c = chains.draw_condition(seed)
        assert (c["transmission"] == "differential") <= (c["structure"] == "ur5" and c["friction"] == "smooth")
        s = chains.draw_condition(seed, hidden="stribeck")
        assert (s["friction"], s["transmission"]) == ("coulomb", "none")
        assert {k: s[k] for k in ("structure", "rate", "excitation", "torque")} == {
            k: c[k] for k in ("structure", "rate", "excitation", "torque")
        }
        assert (c["engine"] == "pinocchio") <= (c["friction"] == "smooth")
    with pytest.raises(ValueError, match="smooth friction"):
        chains.draw_condition(0, structure="ur5", transmission="differential", friction="coulomb")
    with pytest.raises(ValueError, match="smooth friction"):
        chains.draw_condition(0, engine="pinocchio", friction="coulomb")


def test_the_independent_engine_is_what_manus_identifies():
    """A recording of pinocchio's ABA under RK4 (friction and loop written in numpy), the UR5
    with a differential wrist and smooth friction: the true model fitted on it leaves ~0.1 % of
    the torque, and gives back each viscous and friction level within 1 %."""
    from manus.adaptive import fit

    c = chains.case(NULLS[0], engine="pinocchio", log="clean", excitation="closed")
    assert c.condition["engine"] == "pinocchio" and c.rec.structure.transmission is not None
    f = fit(c.rec, c.start)
    assert f.rel_error < 0.003, f.rel_error
    for k, v in c.truth.items():
        if k[:1] == "b" or k[:2] == "Fs":
            assert f.params[k] == pytest.approx(v, rel=0.01), k


def test_a_coupling_counts_only_with_its_joints_and_sign():
    class Verdict:
        def __init__(self, spec, readings=()):
            self.effect, self.spec, self.joint, self.readings = "coupling", spec, 1, list(readings)

    assert chains.same_coupling("coupling:6+5", "coupling:5+6") and chains.same_coupling("coupling:3-2", "coupling:3-2")
    assert not chains.same_coupling("coupling:3-2", "coupling:2+3")
    assert _outcome(Verdict("coupling:3-2"), "coupling", None, "coupling:3-2")["outcome"] == "named"
    assert _outcome(Verdict("coupling:4-3"), "coupling", None, "coupling:3-2")["outcome"] == "wrong"
    assert _outcome(Verdict("coupling:2+3"), "coupling", None, "coupling:3-2")["outcome"] == "wrong"


def test_a_differential_wrist_and_a_pc_log_reach_diagnose_through_the_file():
    c = chains.case(NULLS[0])
    assert (c.condition["transmission"], c.condition["friction"], c.condition["log"]) == (
        "differential",
        "smooth",
        "repeated, jittered",
    )
    assert c.start == f"rigid,viscous,smooth:{c.condition['width']:.4g}"
    assert c.rec.structure.transmission == parse(chains.DIFFERENTIAL, 6)
    assert c.rec.time_base is not None and "repeated rows" in c.condition["time_base"]
    # every repeated row dropped: the repaired grid is the simulated one less those samples
    expected = round(chains.SECONDS * c.condition["rate"]) + 1 - round(c.condition["repeated"] * len(c.rec.t))
    assert abs(len(c.rec) - expected) <= 2
    assert np.all(np.diff(c.rec.t) > 0)


@pytest.mark.parametrize("seed", NULLS)
def test_a_chain_with_nothing_missing_stays_quiet(seed):
    r = judge(seed, None, simulator="chain", baseline=False)
    assert r["outcome"] == "quiet", r


@pytest.mark.parametrize(("seed", "effect"), HIDDEN)
def test_an_effect_on_one_joint_of_a_chain_is_named_relative_to_what_is_left(seed, effect):
    r = judge(seed, effect, simulator="chain", baseline=False)
    assert r["outcome"] == "named" and r["right_joint"], r
    own = next(c for c in r["candidates"] if c["spec"].startswith(effect))
    if effect == "coupling":
        assert chains.same_coupling(r["verdict_spec"], r["condition"]["hidden_spec"])
    else:
        assert own["explains"] < 0.005 and max(r["condition"]["hidden_fraction"]) >= chains.AMPLITUDE


def test_a_geared_robots_smooth_friction_is_named_with_its_motors_width():
    """The xArm7, whose URDF states a 100:1 gear on every joint: its recording keeps the gear
    (read back through its URDF), its friction acts on the motors (levels 1/100 and 1/100² of
    those felt at the joints), and smooth friction hidden behind a start model with Coulomb's sign
    is named, its width within 30 % of the truth's, 100 times what the joints' speeds span
    (the search space of a motor-side effect is the motors', `Span.of`)."""
    from manus.adaptive import diagnose

    c = chains.case(6302, "smooth", robots=("xarm7",), rate=500, excitation="open", torque="exact", log="clean")
    assert c.condition["structure"] == "xarm7" and chains.gear(chains.chain("xarm7")) == 100.0
    N = c.rec.structure.transmission
    assert N is not None and np.allclose(N.matrix, 100.0 * np.eye(7))
    assert c.truth["Fs1"] == pytest.approx(chains.FRICTION["xarm7"][0][0] / 100)
    assert c.truth["b1"] == pytest.approx(chains.FRICTION["xarm7"][1][0] / 100**2)
    width = c.condition["width"]
    assert width > 5.0  # rad/s of the motor; a search among the joints' speeds stops at half their top: 0.55 rad/s here
    d = diagnose(c.rec, c.start)
    v = d.verdict
    assert v is not None and v.effect == "smooth", [x.report() for x in d.candidates]
    assert float(v.found().width) == pytest.approx(width, rel=0.3)  # pyright: ignore[reportAttributeAccessIssue]


def test_the_robots_are_checked():
    with pytest.raises(ValueError, match="robots"):
        chains.draw_condition(0, robots=("kuka",))
    assert {chains.draw_condition(s, robots=("xarm7",))["structure"] for s in range(5)} == {"xarm7"}
    assert chains.draw_condition(3) == chains.draw_condition(3, robots=chains.DRAWN)
