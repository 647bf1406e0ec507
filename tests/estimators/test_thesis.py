"""The thesis's velocity estimator (§3.7): its phase lag at 2 and 5 Hz, its closed-loop poles
(eq. 3.20), and the frequency-response measurement against scipy's closed form."""

from typing import Any

import control
import numpy as np
import pytest
import scipy.signal

from manus import estimators
from manus.estimators.base import FilteredFirstDifference
from manus.estimators.linear import THESIS_CORNER, ffd_noise_gain
from manus.estimators.response import frequency_response

DT = 1e-3


def test_filtered_first_difference_lags_as_the_thesis_says():
    H = frequency_response("filtered_first_difference", [2.0, 5.0], DT)
    lag = -np.degrees(np.angle(H))
    # the bilinear transform of λs/(s + λ): lag = atan(ω_w/λ), ω_w = (2/T) tan(ωT/2)
    w = 2 / DT * np.tan(np.pi * np.array([2.0, 5.0]) * DT)
    np.testing.assert_allclose(lag, np.degrees(np.arctan(w / THESIS_CORNER)), atol=1e-6)
    np.testing.assert_allclose(lag, [3.81, 9.46], atol=0.005)
    assert lag[0] < 4.0 and abs(lag[1] - 9.3) < 0.2  # thesis: "less than 4°" and "9.3°"


def test_measured_response_is_scipys_transfer_function():
    freqs = np.array([0.7, 3.0, 20.0, 90.0, 300.0])
    ffd = estimators.make("filtered_first_difference", dt=DT)
    assert isinstance(ffd, FilteredFirstDifference)
    a, b = ffd.coefficients
    _, h = scipy.signal.freqz([b, -b], [1, -a], worN=freqs, fs=1 / DT)  # pyright: ignore[reportArgumentType] q -> v̂
    np.testing.assert_allclose(
        frequency_response("filtered_first_difference", freqs, DT), h / (2j * np.pi * freqs), atol=1e-9
    )  # relative to q̇ = jω q
    # and its white-noise gain, √Σh², in closed form
    _, imp = scipy.signal.dimpulse(([b, -b], [1, -a], DT), n=20000)
    assert imp is not None and ffd_noise_gain(DT) == pytest.approx(np.sqrt(np.sum(imp[0] ** 2)), rel=1e-9)


def test_closed_loop_poles_of_eq_3_20():
    """k = 100 N/m, b_c = 2 N·s/m, m = 1 kg, b = 1.5 N·s/m, λ = 188.5: −186.5 and −1.7 ± 9.9i."""
    k, bc, m, b, lam = 100.0, 2.0, 1.0, 1.5, THESIS_CORNER
    s: Any = control.tf("s")  # python-control's operators are not typed
    plant = 1 / (m * s**2 + b * s)
    velocity = lam * s / (s + lam)  # eq. 3.19
    loop = control.feedback(k * plant, 1 + bc / k * velocity)  # τ = k(x_d − x) − b_c v̂
    poles: Any = np.sort_complex(control.poles(loop))
    assert poles[0].real == pytest.approx(-186.5, abs=0.05)
    np.testing.assert_allclose(poles[1:].real, -1.7, atol=0.1)  # the thesis rounds −1.77 down
    np.testing.assert_allclose(np.abs(poles[1:].imag), 9.9, atol=0.01)
    # eq. 3.20's denominator itself
    np.testing.assert_allclose(
        np.sort_complex(np.roots([m, m * lam + b, b * lam + bc * lam + k, k * lam])), poles, atol=1e-9
    )
    wn = np.abs(poles[1])
    assert wn / (2 * np.pi) == pytest.approx(1.6, abs=0.05) and -poles[1].real / wn == pytest.approx(0.17, abs=0.01)


def test_default_bandwidths_match_the_thesis_filters_noise():
    """Each linear estimator's default: the same white-noise gain from q to q̂̇ as the thesis's."""
    rng = np.random.default_rng(1)
    noise = rng.standard_normal((10000, 1)) * 1e-3
    ffd = np.std(np.asarray(estimators.run(estimators.make("filtered_first_difference"), noise).qd)[1000:])
    for name in ("kalman_cv", "kalman_ca", "luenberger"):
        std = np.std(np.asarray(estimators.run(estimators.make(name, step=1e-3), noise).qd)[1000:])
        assert std == pytest.approx(ffd, rel=0.03), name
