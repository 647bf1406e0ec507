"""The Type 2 step test: its PSD normalization against scipy, its verdict rules, the rigid
simulation against the exactly sampled linear threshold, and the thesis's shape of the map."""

import numpy as np
import pytest
from scipy import signal

from manus.experiments.stability.linear import LinearAxis
from manus.experiments.stability.search import edge, stability_map
from manus.experiments.stability.steptest import (
    STABLE,
    TYPE1,
    TYPE2,
    Metrics,
    StepTest,
    batched,
    line_amplitude,
    periodogram,
    verdict,
)


def test_periodogram_is_the_fft_periodogram_and_reads_lines_the_same_at_any_rate():
    x = np.random.default_rng(0).normal(size=1000)
    f, p = periodogram(x, 1000.0)
    fs, ps = signal.periodogram(x, 1000.0, window="boxcar", detrend="constant", scaling="spectrum")
    np.testing.assert_allclose(f, fs)
    np.testing.assert_allclose(np.asarray(p)[1:-1], ps[1:-1] * 1000 / 2, rtol=1e-10)  # |X|²/N = N/2 × one-sided
    amplitude = 63e-6
    for rate in (500.0, 1000.0, 2000.0):
        t = np.arange(int(rate)) / rate
        f, p = periodogram(amplitude * np.sin(2 * np.pi * 200 * t + 0.3), rate)
        assert np.max(np.asarray(p)) == pytest.approx(250 * amplitude**2, rel=1e-9)
        assert f[np.argmax(np.asarray(p))] == 200
    assert line_amplitude(1e-6) == pytest.approx(2 * np.sqrt(1e-9))  # 63 µm: 2.6 encoder steps


def test_verdict_rules():
    test = StepTest(spring=1050.0)
    m = Metrics(
        amplitude=np.array([1e-3, 2.6e-3, 2.6e-3, 1e-5, 1e-4, np.nan]),
        move=np.full(6, 0.005 * 1000 / 2050),
        psd=np.array([0, 0, 0, 2e-6, 0, 0]),
        psd_hz=np.full(6, 219.0),
        dominant_hz=np.array([20, 20, 219, 219, 20, 20]),
        samples=np.full(6, 1000),
    )
    # decaying; sustained at the spring's share of the step (2.4 mm, not 5 mm) at 20 Hz, or at
    # 219 Hz; a 200 Hz line above 1e-6; a tiny move below one encoder step; a blow-up
    np.testing.assert_array_equal(verdict(m, test), [STABLE, TYPE1, TYPE2, TYPE2, STABLE, TYPE1])
    move = m.move.copy()
    move[4] = 1e-5  # the step moves the equilibrium less than an encoder step: judged at one step
    assert verdict(m._replace(move=move), test)[4] == TYPE1
    assert verdict(m._replace(move=move), test.with_(quantum=2e-4))[4] == STABLE


def test_rigid_step_test_meets_the_sampled_linear_threshold():
    """Without the shaft and the quantizer the simulated step test loses stability exactly
    where the sampled linear model of eq. 4.1 with the delay says."""
    test = StepTest(compliance=False, quantum=0.0)
    lin = LinearAxis()
    b_c = np.array([0.0, 0.0, 5.0, 5.0])
    k = np.array([lin.k_max(b, 1000.0) for b in b_c]) * np.array([0.98, 1.02, 0.98, 1.02])
    m = batched(test)(k, b_c)
    np.testing.assert_array_equal(verdict(m, test), [STABLE, TYPE1, STABLE, TYPE1])


@pytest.fixture(scope="module")
def thesis_map():
    test = StepTest()
    return test, stability_map(
        test, [0.0, 5.0, 15.0, 25.0], [300.0, 600.0, 1200.0, 2400.0, 4800.0, 9600.0], progress=False
    )


def test_map_has_the_thesis_shape(thesis_map):
    """Fig. 4-25: a positive-sloping Type 1 edge at low damping, a negative-sloping Type 2 edge
    at high damping."""
    _, smap = thesis_map
    np.testing.assert_array_equal(smap.limit_kind, [TYPE1, TYPE1, TYPE2, TYPE2])
    np.testing.assert_array_equal(smap.limit, [600.0, 2400.0, 2400.0, 1200.0])
    assert (smap.kinds[:, 0] == STABLE).all()  # soft enough is stable everywhere here


def test_type2_edge_is_the_shaft_mode_losing_stability(thesis_map):
    """The 200 Hz criterion fires close to where the sampled linear model with the shaft mode
    loses stability (quantization only makes the vibration visible)."""
    test, _ = thesis_map
    e = edge(test, [20.0], 300.0, 9600.0)
    assert e.kind[0] == TYPE2
    assert e.limit[0] == pytest.approx(test.linear().k_max(20.0, 1000.0), rel=0.1)


def test_negative_damping_limit_is_about_minus_one_and_a_half(thesis_map):
    test, _ = thesis_map
    e = edge(test, [10.0], 0.0, -3.0, along="b_c", points=(16, 24))
    assert e.kind[0] == TYPE1
    assert -1.5 < e.limit[0] < -1.44  # thesis: −1.5 N·s/m, as much as the physical damping
    assert e.limit[0] == pytest.approx(test.linear().b_c_min(10.0, 1000.0), abs=abs(e.step[0]) + 0.005)
