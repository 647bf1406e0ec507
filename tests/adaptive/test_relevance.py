"""Relevance relative to what is left, per joint: a candidate significant on a joint and removing a
large share of the error left there is named even where it is under `min_share` of all the torque
(a hump on a model already right to half a percent; an effect of a few percent of one wrist joint's
torque on a seven-joint chain), while recordings with nothing missing stay quiet."""

import numpy as np
import pytest

from manus.adaptive import diagnose
from manus.adaptive.diagnosis.significance import FLOOR, LEFT, OnJoint, on_joints
from manus.experiments import calibration


def test_on_joints_measures_what_is_left_per_joint():
    """Two joints, 20 blocks: joint 1 loses 3/4 of its squared error (half its error: 1 − √¼),
    joint 2 nothing; the shares of each joint's torque from Σ τ² by hand."""
    before = np.ones((20, 2)) * [4.0, 1.0]
    after = before * [0.25, 1.0]
    after[::2, 1] *= 1.01  # (joint 2: no change on average, noisy)
    after[1::2, 1] *= 0.99
    torque = np.array([8000.0, 100.0])
    one, two = on_joints(before, after, torque)
    assert one.joint == 0 and one.left == pytest.approx(0.5)
    assert one.share == pytest.approx(np.sqrt((80 - 20) / 8000))
    assert one.p_value < 1e-6 and two.p_value > 0.1
    assert two.left == pytest.approx(0.0, abs=1e-9)


def test_the_rule_needs_significance_and_a_share_of_the_joint():
    level, min_share = 0.005, 0.005
    assert OnJoint(0, 0.05, 0.02, 1e-4).relevant(level, min_share)  # 2 % of the joint's torque
    assert OnJoint(0, LEFT, FLOOR, 1e-4).relevant(level, min_share)  # a quarter of what is left
    assert not OnJoint(0, 0.9, 0.5 * FLOOR, 1e-9).relevant(level, min_share)  # a quantizer's pattern
    assert not OnJoint(0, 0.2, 0.004, 1e-4).relevant(level, min_share)  # neither
    assert not OnJoint(0, 0.6, 0.02, 0.01).relevant(level, min_share)  # not significant there


def test_a_small_hump_on_a_nearly_right_model_is_named():
    """The calibration's axis at 1 kHz, exact torque: a Stribeck hump hidden at 0.4 % of the torque
    (under `min_share`), on a model otherwise right to a few tenths of a percent. Over all the torque
    it is too small to count; relative to what is left it removes most of it, and is named."""
    c = calibration.case(
        9,
        "stribeck",
        amplitude=0.004,
        structure="axis",
        rate=1000,
        excitation="reaching",
        torque="exact",
        hold="stated",
    )
    d = diagnose(c.rec, c.start)
    strib = next(x for x in d.candidates if x.effect == "stribeck")
    assert strib.detail["explains"] < 0.005
    assert d.verdict is not None and d.verdict.effect == "stribeck", [(x.spec, x.p_value, x.note) for x in d.candidates]
    assert "relevant relative to what is left" in d.verdict.note
    before = diagnose(c.rec, c.start, per_joint=False)
    assert before.verdict is None or before.verdict.effect != "stribeck"
