"""The controller registry: names, gains, estimators by name, and clear refusals."""

from typing import cast

import pytest

from manus.adaptive import CONTROLLERS, Composite, Impedance, SlotineLi, make_controller
from manus.estimators.base import FilteredFirstDifference
from manus.plants import Model
from manus.plants.errors import ManusError
from manus.plants.structures import Axis, Manus2

MODEL = Model(Manus2(), "rigid,viscous")


def test_every_name_builds_its_controller():
    assert CONTROLLERS == ("impedance", "slotine-li", "slotine-li-composite")
    imp = make_controller("impedance", MODEL, 1e-3, stiffness=50.0, damping=2.0)
    assert isinstance(imp, Impedance) and float(imp.stiffness[1]) == 50.0
    sl = make_controller("slotine-li", MODEL, 1e-3, "first_difference", gamma={"b1": 3.0}, kd=[4.0, 6.0])
    assert isinstance(sl, SlotineLi) and sl.composite is None
    assert list(sl.gamma) == [0.2, 0.2, 0.5, 3.0, 5.0] and list(sl.kd) == [4.0, 6.0]  # thesis Γ for a1..a3
    assert sl.lead == 0.0005 and sl.velocity_lag == pytest.approx(0.0005)
    comp = cast(
        SlotineLi, make_controller("slotine-li-composite", Model(Axis(n_joints=1), "rigid,coulomb"), 1e-3, weight=7.0)
    )
    assert comp.composite == Composite(weight=7.0)


def test_estimators_come_by_name_and_model_based_ones_use_the_controllers_model():
    sl = cast(SlotineLi, make_controller("slotine-li", MODEL, 1e-3, "kalman_model"))
    assert sl.estimator.model is not None and sl.estimator.model.names == MODEL.names
    assert sl.velocity_lag == 0.0
    ffd = cast(SlotineLi, make_controller("slotine-li", MODEL, 1e-3, FilteredFirstDifference()))
    assert ffd.velocity_lag == pytest.approx(1 / 188.5, rel=0.01)  # the filter's 1/λ


@pytest.mark.parametrize(
    "args, kwargs, match",
    [
        (("pid", MODEL, 1e-3), {}, "unknown controller 'pid'"),
        (("slotine-li", MODEL, 1e-3, "psychic"), {}, "unknown estimator 'psychic'"),
        (("slotine-li", MODEL, 1e-3), {"weight": 3.0}, "weight belong to slotine-li-composite"),
        (("slotine-li", MODEL, 1e-3), {"gains": 3.0}, "slotine-li has no setting gains \\(its settings: gamma, lam"),
        (("slotine-li-composite", MODEL, 1e-3), {"bandwidth": -5.0}, "composite bandwidth must be positive"),
        (("impedance", MODEL, 1e-3), {"stiffness": -30.0}, "stiffness must be positive definite"),
        (("slotine-li", "rigid", 1e-3), {}, "needs a manus.plants.effects.Model"),
        # at 50 Hz the thesis's 30 Hz filter is above Nyquist: no Kalman bandwidth has its noise
        (
            ("slotine-li", MODEL, 1 / 50, "kalman_cv"),
            {},
            "kalman_cv: no bandwidth .* 30 Hz filtered first difference at 50 Hz \\(its corner is above Nyquist",
        ),
    ],
)
def test_bad_requests_are_refused_with_a_clear_message(args, kwargs, match):
    with pytest.raises(ManusError, match=match):
        make_controller(*args, **kwargs)
