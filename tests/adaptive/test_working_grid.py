"""The working grid (`manus.adaptive.identify.prepare`): where the rate is far above the
identification band, the columns and the torque are computed on every `stride`-th sample. The
fit it gives is the full-rate fit's: on the thesis's arm recorded at 5 kHz, both give back the
truth's parameters, and the two agree within their standard deviations; a delay of a fraction of
the grid's period is still found; recordings whose rate is near the band keep it."""

import numpy as np
import pytest

import manus.adaptive.identify.prepare as prep
from manus.adaptive.identify.fit import fit
from manus.experiments import calibration
from manus.plants.effects import Delay
from manus.plants.recording import from_trajectory

MODEL = "rigid,viscous,coulomb"


def arm(rate: int, extra: tuple = (), noise: float = 0.02, seconds: float = 8.0):
    """The thesis's arm under impedance control (a multi-sine), its nominal parameters, white
    noise of `noise` × RMS on the recorded torque."""
    setup = calibration.ARM
    traj = calibration.simulate_case(setup, rate, "multisine", dict(setup.nominal), extra, seconds, 3)
    rec = from_trajectory(traj, rate, "manus2", 131072, setup.meta())
    rec.qd, rec.extra = None, {}
    rng = np.random.default_rng(7)
    rec.tau = rec.tau + rng.standard_normal(rec.tau.shape) * noise * np.sqrt(np.mean(rec.tau**2, axis=0))
    return rec


@pytest.fixture(scope="module")
def fast():
    return arm(5000)


def test_a_5khz_recording_is_worked_on_a_coarser_grid_with_the_full_rates_parameters(fast, monkeypatch):
    data = prep.prepare(fast)
    assert data.stride == int(1 / (prep.WORK_RATE * data.cutoff_hz * data.dt)) >= 4
    assert np.all(data.rows % data.stride == 0)
    assert data.tau(full=True).shape[0] == -(-len(fast) // data.stride)
    # about four rows per cut-off period, as at full rate
    assert np.median(np.diff(data.rows)) * data.dt * data.cutoff_hz == pytest.approx(0.25, rel=0.2)
    work = fit(data, MODEL, method="ls")
    monkeypatch.setattr(prep, "WORK_RATE", np.inf)
    full_data = prep.prepare(fast)
    assert full_data.stride == 1 and full_data.cutoff_hz == data.cutoff_hz
    full = fit(full_data, MODEL, method="ls")
    truth = calibration.ARM.nominal
    for k, v in truth.items():
        if v:
            assert work.params[k] == pytest.approx(v, rel=0.01, abs=3 * work.stds[k]), k
            assert abs(work.params[k] - full.params[k]) < 2 * full.stds[k], k
    assert work.rel_error == pytest.approx(full.rel_error, rel=0.05)


def test_a_delay_under_the_grids_period_is_found(monkeypatch):
    """0.9 ms at 5 kHz (4.5 samples): under the working grid's period (the torque is shifted at full rate, then
    read on the grid)."""
    rec = arm(5000, (Delay(seconds=0.0009),), noise=0.01, seconds=6.0)
    data = prep.prepare(rec)
    assert data.stride * data.dt > 0.0009
    f = fit(data, MODEL + ",delay", method="ls")
    assert f.delay == pytest.approx(0.0009, abs=1e-4)


def test_recordings_near_their_band_keep_their_rate():
    """The calibrated cases: the arm at 1 kHz (a 15 Hz band) and at 200 Hz."""
    for rate in (1000, 200):
        data = prep.prepare(arm(rate, seconds=4.0))
        assert data.stride == 1, (rate, data.cutoff_hz)
