"""The discovery loop's steps: a step that changes nothing is undone and the next significant
candidate tried; a structural mode is proposed only where the sample rate can show it, and ranked
by what it removes from the torque error (nothing: it comes after every candidate with columns)."""

import numpy as np
import pytest

from manus.adaptive import diagnose, discover
from manus.adaptive.diagnosis import modes
from manus.adaptive.diagnosis.discover import kept, to_try
from tests.adaptive import hidden

FRICTION = {"coulomb", "smooth"}  # a friction level at breakaway, sign-like or smooth at zero speed


@pytest.fixture(scope="module")
def square_wave():
    return hidden.square_wave_recording()


def test_a_mode_comes_after_a_candidate_that_removes_torque_error(square_wave):
    """The square wave rings the 218.7 Hz shaft mode; with Coulomb friction left out of the start,
    Coulomb removes most of the torque error and the mode (no inverse-dynamics columns) nothing:
    the friction level is proposed first (Coulomb, or its smooth reading), the mode stays proposable
    and says why it waits."""
    d = diagnose(square_wave, "rigid,viscous")
    mode = next(c for c in d.candidates if c.effect == "compliance")
    assert d.verdict is not None and d.verdict.effect in FRICTION
    assert mode.proposable and "removes nothing from the torque error" in mode.note
    order = [c.effect for c in to_try(d)]
    assert order[0] in FRICTION and order[-1] == "compliance"


def test_discover_adds_the_friction_before_the_mode(square_wave):
    """From rigid,viscous the loop adds the friction level first (the torque error falls, by more
    than `min_share` of the torque: the rest is the mode's ringing) and only then records the
    mode, which it cannot refit. Each step is handed to `on_step` as it is added (a figure of it
    can be drawn while the loop goes on)."""
    seen = []
    r = discover(square_wave, "rigid,viscous", max_steps=3, on_step=seen.append)
    assert len(seen) == len(r.steps) and all(a is b for a, b in zip(seen, r.steps, strict=True))
    effects = [s.effect for s in r.steps]
    assert effects[0] in FRICTION, effects
    first = r.steps[0]
    assert np.sqrt(first.rel_error_before**2 - first.rel_error**2) > 0.005
    if "compliance" in effects:
        assert effects[-1] == "compliance" and r.stopped == "compliance (not refitted)"


def test_a_step_that_changes_nothing_is_not_kept(square_wave):
    """`kept` measures a step on the diagnosis's held-out blocks: the model against itself changes
    nothing; the verdict's own fit removes what the diagnosis judged it to remove."""
    d = diagnose(square_wave, "rigid,viscous")
    assert d.verdict is not None
    same, said = kept(d, d.base, d.base)
    assert not same and "->" in said
    better, _ = kept(d, d.base, d.verdict.fitted())
    assert better


def test_discover_undoes_a_step_that_changes_nothing_and_tries_the_next(square_wave, monkeypatch):
    """A verdict whose refit leaves the held-out error as it was is undone, said in the notes, and
    the next significant candidate of the same diagnosis is added instead (here: every step's
    first candidate is declared to change nothing)."""
    from manus.adaptive.diagnosis import discover as loop

    refused: list[str] = []
    real = loop.kept

    def first_changes_nothing(d, before, after):
        first = to_try(d)[0]
        if after.model.has(first.effect) and not before.model.has(first.effect):
            refused.append(first.effect)
            return False, "forced"
        return real(d, before, after)

    monkeypatch.setattr(loop, "kept", first_changes_nothing)
    r = discover(square_wave, "rigid,viscous", max_steps=1)
    assert refused and refused[0] in FRICTION
    assert any(f"{refused[0]}" in n and "undone" in n for n in r.notes)
    assert r.steps and r.steps[0].effect != refused[0]
    assert r.steps[0].verdict.effect == r.steps[0].effect  # the step names the candidate it added


def _mode(f_hz: float, df: float) -> modes.Mode:
    freq = np.arange(0, 500, df)
    z = np.zeros(4)
    return modes.Mode(f_hz, 0.02, 0.1, 0, True, z, z, freq, z, z, z)


def test_a_mode_is_shown_only_where_the_sample_rate_can_show_it():
    """Well below Nyquist (at most 0.6 of fs/2), above the identification band, on at least 8 bins."""
    assert _mode(218.7, 3.9).unresolved(1000, 40.0) == ""
    assert _mode(22.9, 1.0).unresolved(100, 10.0) == ""  # 0.46 of Nyquist, 23 bins: shown (ranked last)
    assert "Nyquist" in _mode(35.0, 1.0).unresolved(100, 10.0)  # 0.7 of Nyquist (50 Hz)
    assert "inside the identification band" in _mode(25.0, 1.0).unresolved(1000, 30.0)
    assert "bins" in _mode(25.0, 3.9).unresolved(1000, 10.0)  # 6.4 bins below it
    assert _mode(0.6 * 50, 1.0).unresolved(100, 10.0) == ""  # the bound itself is shown
