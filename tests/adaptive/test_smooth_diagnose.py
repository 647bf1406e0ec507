"""Diagnose proposes smooth friction (Fs tanh(q̇/w)) where the data show a finite width: in
Coulomb's place when the model holds Coulomb friction, its width within 30 % of the truth and the
error falling; on a recording whose friction is Coulomb's sign it proposes none."""

import numpy as np
import pytest

from manus.adaptive import diagnose
from manus.adaptive.diagnosis.candidates import offered
from manus.experiments import calibration
from manus.plants.effects import Cogging, Model, Smooth, Stribeck
from manus.plants.recording import from_trajectory
from manus.plants.structures import Manus2


def recording(structure: str, width: float, seed: int, coulomb: bool = False, noise: float = 0.15, rate=1000):
    """A calibration setup's multi-sine run (impedance control) with the nominal rigid and viscous
    terms and friction Fs tanh(q̇/w) at the nominal Coulomb levels (or, `coulomb`, the nominal
    Coulomb friction itself), white noise of `noise` × RMS on the recorded torque."""
    setup = calibration.SETUPS[structure]
    params = dict(setup.nominal)
    if not coulomb:
        params.update({"Fs" + k[2:]: v for k, v in setup.nominal.items() if k.startswith("Fc")})
        params.update({k: 0.0 for k in setup.nominal if k.startswith("Fc")})
    nonlinear = (Cogging(order=39.0), Stribeck(vs=setup.stribeck_vs), Smooth(width=width))
    seconds = 8.0
    traj = calibration.simulate_case(setup, rate, "multisine", params, (), seconds, seed, None, nonlinear)
    rec = from_trajectory(
        traj, rate, "manus2" if structure == "arm" else "axis", 131072 if structure == "arm" else None, setup.meta()
    )
    rec.qd, rec.extra = None, {}
    rng = np.random.default_rng(seed)
    rec.tau = rec.tau + rng.standard_normal(rec.tau.shape) * noise * np.sqrt(np.mean(rec.tau**2, axis=0))
    return rec


def _smooth(d):
    return next(c for c in d.candidates if c.effect == "smooth")


def test_hidden_smooth_friction_is_proposed_in_coulombs_place_on_an_axis():
    width = 0.01  # m/s, a quarter of the motion's typical speed
    d = diagnose(recording("axis", width, seed=3), "rigid,viscous,coulomb")
    v = d.verdict
    assert v is not None and v.effect == "smooth", [c.report() for c in d.candidates]
    found = float(v.found().width)  # pyright: ignore[reportAttributeAccessIssue]
    assert found == pytest.approx(width, rel=0.3)
    assert v.detail["replaces"] == ["coulomb"] and "in place of coulomb" in v.note
    after = v.fitted()
    assert not after.model.has("coulomb") and after.model.has("smooth")
    assert after.params["Fs1"] == pytest.approx(calibration.AXIS.nominal["Fc1"], rel=0.1)
    assert after.rel_error < 0.5 * d.base.rel_error and v.cv_error_reduction > 0.3


def test_coulomb_friction_gets_no_smooth_law():
    """The truth is Coulomb's sign: the smooth candidate is not proposed (the width the data
    would need lies below what they resolve, or nothing beyond the sign is significant)."""
    d = diagnose(recording("axis", 0.01, seed=4, coulomb=True), "rigid,viscous,coulomb")
    c = _smooth(d)
    assert not c.proposable, c.report()
    assert d.verdict is None or d.verdict.effect != "smooth"


def test_on_the_arm_at_200_hz_smooth_friction_is_named_with_its_width():
    width = 0.1  # rad/s
    d = diagnose(recording("arm", width, seed=1, rate=200), "rigid,viscous,coulomb")
    v = d.verdict
    assert v is not None and v.effect == "smooth", [c.report() for c in d.candidates]
    assert float(v.found().width) == pytest.approx(width, rel=0.3)  # pyright: ignore[reportAttributeAccessIssue]
    assert v.detail["replaces"] == ["coulomb"]
    # the error falls (little: what is left is mostly the noise, 15 % of the torque's RMS)
    assert v.fitted().rel_error < d.base.rel_error and v.cv_error_reduction > 0.02


def test_smooth_is_offered_on_coulomb_in_its_place_unless_stribeck_sits_on_it():
    from manus.plants.effects import Span

    span = Span(1e-3, 10.0, np.ones(2), 1e-5, np.array([0.8, 0.8]), (False, False), 1e-3, 16.0, np.full(2, 0.25))

    def offer(spec):
        return next(o for o in offered(Model(Manus2(), spec), span, (False, False))[0] if o.effect.name == "smooth")

    assert offer("rigid,viscous,coulomb").replaces == ("coulomb",)
    assert offer("rigid,viscous,coulomb,stribeck").replaces == ()  # Stribeck is offered only on top of Coulomb
    assert len(offer("rigid,viscous,coulomb").values) > 10
    tried, notes = offered(Model(Manus2(), "rigid,viscous"), span, (False, False))
    assert "smooth" not in [o.effect.name for o in tried]  # Coulomb's sign first, its width refines it
    assert any(n.startswith("smooth: offered only on top of coulomb") for n in notes)
    held = offered(Model(Manus2(), "rigid,viscous,smooth:0.1"), span, (False, False))[0]
    assert "smooth" not in [o.effect.name for o in held] and "coulomb" in [o.effect.name for o in held]
