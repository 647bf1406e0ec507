"""A seeded subset of the chain calibration (`manus.experiments.chains`, `manus bench diagnose
--calibrate --simulator chain`): the UR5 and the Panda with nothing missing stay quiet, at a low
and a high rate, open and closed loop, with and without noise on the torque; an effect of 3 % of
ONE joint's torque, far under 0.5 % of all the torque (0.1 % here), is named on its joint."""

import pytest

from manus.experiments import chains
from manus.experiments.judging import judge

pytest.importorskip("pinocchio")  # (example-robot-data comes with it)

# (seeds of `manus bench diagnose --calibrate --simulator chain --recordings 3 --effects offset,stribeck`)
NULLS = (779308542, 821328062)  # the UR5 at 100 Hz open loop; the Panda at 100 Hz closed loop; exact torque
HIDDEN = ((465539299, "offset"),)  # the Panda at 200 Hz, open loop: an offset of 5 % of joint 7's torque


@pytest.mark.parametrize("seed", NULLS)
def test_a_chain_with_nothing_missing_stays_quiet(seed):
    r = judge(seed, None, simulator="chain", baseline=False)
    assert r["outcome"] == "quiet", r


@pytest.mark.parametrize(("seed", "effect"), HIDDEN)
def test_an_effect_on_one_joint_of_a_chain_is_named_relative_to_what_is_left(seed, effect):
    r = judge(seed, effect, simulator="chain")
    assert r["outcome"] == "named" and r["right_joint"], r
    own = next(c for c in r["candidates"] if c["spec"] == effect)
    assert own["explains"] < 0.005 and max(r["condition"]["hidden_fraction"]) >= chains.AMPLITUDE
