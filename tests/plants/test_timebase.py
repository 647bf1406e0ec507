"""A recording's time base (`manus.plants.timebase`): what a PC logger does to a rig's uniform
samples, done to simulated recordings whose truth is known, found and named, and repaired so that
the fit is the clean recording's; clean recordings (simulated at 1000 and 200 Hz, the EMPS files,
the DFKI double pendulum) are left exactly as they are.

The corruptions are `manus.experiments.logs`'s, each from the logger's physics: repeated rows
(5 % of the moving rows), jitter (±20 % of the period), alternating periods (10 and 12 ms at
90.9 Hz: the median step is one of them, the rate read from it 9 % off, the inertia ~17 %), held
positions (resampled 10 times), a PC loop waking late (mean 15 % of a period) and a device's log
under load (3 % of the packets stalled, those behind them bunched).
"""

import math
import warnings

import numpy as np
import pytest

from manus.adaptive import fit
from manus.experiments.calibration import case
from manus.experiments.logs import alternate_stamps, device_log, hold_positions, jitter_stamps, pc_logger, repeat_rows
from manus.plants import recording
from manus.plants.gaps import gaps
from manus.plants.recording import Recording, repair
from manus.plants.timebase import JITTER, TimeBase, examine, grid, stamp_resolution
from tests.conftest import SHARED

MODEL = "rigid,viscous,coulomb"


def _far(a, b) -> float:
    """The largest parameter difference, relative to the parameter (or to 3 std where it is
    smaller: a friction level near zero)."""
    scale = {k: max(abs(v), 3 * (b.stds[k] if math.isfinite(b.stds[k]) else 0.0)) for k, v in b.params.items()}
    return max(abs(a.params[k] - b.params[k]) / scale[k] for k in b.params)


# -- clean recordings: nothing found, nothing changed ---------------------------------------------


def _clean_recordings():
    for seed in range(6):
        for rate in (1000, 200):
            yield f"calibration seed {seed} at {rate} Hz", case(seed, None, rates=(rate,)).rec
    for seed in (0, 1):  # open-loop torque steps on a compliant shaft: stick-slip stops the motion for a row
        yield f"calibration seed {seed}, a shaft mode", case(seed, "compliance", rates=(1000,)).rec
    for path in sorted((SHARED / "data" / "emps").glob("*.mat")) + sorted(
        (SHARED / "data" / "real" / "dfki_double_pendulum").glob("*.csv")
    ):
        yield path.name, recording.read(path)


def test_clean_recordings_are_left_exactly_as_they_are():
    """Fourteen simulated recordings (six seeds at 1000 and 200 Hz, two with a shaft mode ringing
    through stick-slip under open-loop steps), the two EMPS files and the six DFKI recordings:
    no finding, the same object back; read from a file, no `time_base`."""
    found = []
    n = 0
    for name, rec in _clean_recordings():
        n += 1
        tb, keep, stamps = examine(rec)
        if tb or not keep.all() or stamps is not None or repair(rec) is not rec or rec.time_base is not None:
            found.append(f"{name}: {tb.note}")
        assert tb.jitter < JITTER / 10, name  # (a uniform clock: its stamps' quantization only)
    assert n >= 14 + 8 * SHARED.exists()
    assert not found, f"{len(found)} of {n} clean recordings read as blurred: {found}"


def test_a_clean_file_reads_back_unchanged_and_a_blurred_one_with_a_note(tmp_path):
    rec = case(1, None, rates=(1000,)).rec
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no note
        back = recording.read(recording.write(rec, tmp_path / "clean.csv"))
    assert back.time_base is None and len(back) == len(rec)
    assert np.allclose(back.t, rec.t, rtol=0, atol=1e-12) and np.allclose(back.q, rec.q, rtol=1e-11, atol=0)
    bad = recording.write(alternate_stamps(repeat_rows(rec, 0.05, np.random.default_rng(1))[0]), tmp_path / "bad.csv")
    with pytest.warns(recording.RecordingNote, match=r"bad.csv: time base: \d+ repeated rows .* stamps scatter"):
        back = recording.read(bad)
    assert back.time_base and back.time_base.repaired and gaps(back).at.size != 0


def test_stated_rate_of_alternating_stamps_is_their_grids(tmp_path):
    """A cobot's log at 90.9 Hz, stamps 10 and 12 ms apart in turn, its metadata stating the rate:
    read (the median step, 10 or 12 ms, is 9 % off the rate; the grid's 11 ms is not), put on
    the grid, said."""
    k = np.arange(2000)
    t = np.cumsum(np.r_[0.0, np.where(k[1:] % 2 == 1, 0.010, 0.012)])
    q = np.round(np.sin(2 * np.pi * 0.5 * t) / 1e-4)[:, None] * 1e-4
    rec = Recording(t, q, np.cos(2 * np.pi * 0.5 * t)[:, None], None, {"sample_rate_hz": "90.9091"})
    with pytest.warns(recording.RecordingNote, match=r"stamps scatter by 4.55 % .* steps 10 to 12 ms"):
        back = recording.read(recording.write(rec, tmp_path / "cobot.csv"))
    assert back.time_base and back.time_base.rate_hz == pytest.approx(1000 / 11)
    assert np.allclose(np.diff(back.t), 0.011)


# -- the stamps' grid -----------------------------------------------------------------------------


@pytest.mark.parametrize("sigma", [0.05, 0.2])
def test_the_grid_is_found_through_jitter_and_lost_samples(sigma):
    """12000 samples at 1 kHz, 5 % lost, stamps with Gaussian jitter: the period to 1e-5 (a
    drift of a tenth of a period over the recording), each stamp within half a period of its
    sample indexed right."""
    rng = np.random.default_rng(3)
    i = np.flatnonzero(rng.random(12000) >= 0.05)
    e = rng.normal(0, sigma, i.size)
    t = 7.25 + (i + e) * 1e-3
    index, _, T = grid(t)
    assert abs(T / 1e-3 - 1) < 1e-5
    near = np.abs(e) < 0.45
    assert np.all((index - (i - i[0]))[near] == (index - (i - i[0]))[near][0])


def test_alternating_steps_have_the_period_between_them():
    k = np.arange(3000)
    t = np.cumsum(np.r_[0.0, np.where(k[1:] % 2 == 1, 0.010, 0.012)])
    index, _, T = grid(t)
    assert abs(T - 0.011) < 1e-9 and np.array_equal(index, k)


def test_the_stamps_resolution():
    """A decimal digit (microseconds), float32's spacing, float64's."""
    assert stamp_resolution(np.round(np.arange(5000) * 0.0020001, 6)) == pytest.approx(1e-6)
    t32 = (np.arange(12000) * 1e-3).astype(np.float32).astype(float)
    assert stamp_resolution(t32) == float(np.spacing(np.float32(t32[-1])))
    assert stamp_resolution(np.arange(100) * math.pi * 1e-3) < 1e-15


# -- corrupted recordings: found, named, repaired -------------------------------------------------

SEEDS = (0, 5, 7)  # an axis under a multi-sine, the arm reaching and under a multi-sine


@pytest.fixture(scope="module")
def cases():
    return {(seed, rate): case(seed, None, rates=(rate,)).rec for seed in SEEDS for rate in (1000, 200)}


def test_repeated_rows_are_found_and_dropped(cases):
    """Every repeated row found is one that was copied; nearly all copies are found (those where
    a joint moves more than `MOVING_STEPS` encoder steps per sample on both sides, or into or out
    of a short run); the copies' slots are lost samples, left as gaps."""
    for (seed, rate), rec in cases.items():
        bad, pick = repeat_rows(rec, 0.05, np.random.default_rng(seed))
        tb, keep, stamps = examine(bad)
        dropped = np.flatnonzero(~keep)
        assert set(dropped) <= set(pick), (seed, rate)
        assert tb.repeated_rows == dropped.size >= 0.8 * pick.size, (seed, rate, tb.repeated_rows, pick.size)
        assert "repeated rows" in tb.note and tb.repaired and stamps is None and not tb.jittered
        fixed = repair(bad)
        assert fixed.time_base == tb and len(fixed) == len(bad) - dropped.size
        assert int(gaps(fixed).missing.sum()) == dropped.size


def test_jittered_and_alternating_stamps_are_put_on_their_grid(cases):
    for (seed, rate), rec in cases.items():
        rng = np.random.default_rng(seed)
        for bad, share in ((jitter_stamps(rec, 0.2, rng), 0.2 / math.sqrt(3)), (alternate_stamps(rec), 1 / 22)):
            tb, keep, _ = examine(bad)
            assert tb.jittered and keep.all() and tb.jitter == pytest.approx(share, rel=0.05), (seed, rate, tb.note)
            assert "stamps scatter" in tb.note
            fixed = repair(bad)
            assert fixed.sample_rate_hz == pytest.approx(rate, rel=1e-5)
            assert np.allclose(np.diff(fixed.t), 1 / rate, rtol=1e-5, atol=0)
            assert not gaps(fixed)


def test_a_device_log_under_load_keeps_every_sample_in_order(cases):
    """Stamps bunched by a device's stalls are put back on the grid without losing a row (a
    row is dropped for its stamp): the rows and their order are kept, the
    slots are strictly increasing, and nearly every row is back on its own slot."""
    for (seed, rate), rec in cases.items():
        bad = device_log(rec, 0.03, np.random.default_rng(seed))
        tb, keep, _ = examine(bad)
        assert keep.all(), (seed, rate, tb.note)
        fixed = repair(bad)
        assert len(fixed) == len(rec) and np.array_equal(fixed.q, rec.q) and np.array_equal(fixed.tau, rec.tau)
        assert np.all(np.diff(fixed.t) > 0.5 / rate)
        on_slot = np.abs(fixed.t - (fixed.t[0] + (rec.t - rec.t[0]))) < 0.5 / rate
        assert on_slot.mean() > 0.95, (seed, rate, on_slot.mean())


def test_held_positions_are_found_and_one_row_per_run_kept(cases):
    for (seed, rate), rec in cases.items():
        bad = hold_positions(rec, 10)
        tb = examine(bad)[0]
        assert tb.held_every == 10 and tb.repaired and "resampled 10x" in tb.note, (seed, rate)
        fixed = repair(bad)
        assert len(fixed) == len(rec) and np.array_equal(fixed.q, rec.q) and np.allclose(fixed.tau, rec.tau)
        assert fixed.sample_rate_hz == pytest.approx(rate) and fixed.meta["sample_rate_hz"] == f"{rate:.12g}"


@pytest.mark.slow
def test_the_repaired_recording_fits_as_the_clean_one_and_the_blurred_one_does_not(cases):
    """Each corruption over three seeds at 1000 and 200 Hz: the repaired recording's rel_error
    within twice the clean one's (plus 0.5 %) and its parameters within 5 % of the clean fit's;
    unrepaired, the staircase of copied or held positions reads as a broadband motion (the
    cut-off goes to Nyquist, rel_error ≥ 4 times the clean one's), and alternating stamps give
    the wrong period (parameters 17 % off); jittered stamps alone the analysis never reads."""
    for (seed, rate), rec in cases.items():
        clean = fit(rec, MODEL)
        rng = np.random.default_rng(seed)
        blurred = {
            "repeated": repeat_rows(rec, 0.05, rng)[0],
            "jitter": jitter_stamps(rec, 0.2, rng),
            "alternating": alternate_stamps(rec),
            "held": hold_positions(rec, 10),
            "pc logger": pc_logger(rec, 0.15, rng),
            "repeated and jitter": jitter_stamps(repeat_rows(rec, 0.05, rng)[0], 0.2, rng),
        }
        for name, bad in blurred.items():
            fixed = repair(bad)
            assert fixed.time_base, (seed, rate, name)
            good = fit(fixed, MODEL)
            where = (seed, rate, name, clean.rel_error, good.rel_error, fixed.time_base.note)
            assert good.rel_error <= 2 * clean.rel_error + 0.005 and _far(good, clean) < 0.05, where
            if name == "jitter":
                continue
            worse = fit(bad, MODEL)
            if name == "alternating":
                assert _far(worse, clean) > 0.15, where
            elif name != "pc logger" or rate == 200:
                assert worse.rel_error > 4 * clean.rel_error, (where, worse.rel_error)


def test_the_finding_reads_as_one_line():
    tb = TimeBase(
        1000.0, repeated_rows=12, jitter=0.116, jittered=True, lost=12, period_steps=(6.5e-4, 1.35e-3), repaired=True
    )
    assert "\n" not in tb.note and tb.note.startswith("time base: 12 repeated rows")
    assert set(tb.report()) == {"rate_hz", "repeated_rows", "jitter", "held_rows", "repaired", "note"}
    assert not TimeBase(1000.0)
