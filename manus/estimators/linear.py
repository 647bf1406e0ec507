"""Defaults for the linear estimators: every tunable one starts with the thesis filter's noise.

The thesis chose λ = 188.5 rad/s for its filtered first difference (eq. 3.19) as the trade-off
between quantization noise and lag. The Kalman filters and Luenberger observers default to the
bandwidth at which *their* velocity estimate carries the same white measurement noise as that
filter (the same √Σh² of the impulse response from position to velocity), so that comparing them
with the thesis's estimator compares lag and tracking at equal noise. At 1 kHz that is about
290 rad/s for the constant-acceleration Kalman filter, 460 rad/s for the constant-velocity one.
The ratio does not depend on the units of position (the noise scales out), only on the period.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.linalg
import scipy.optimize

from manus.estimators.base import FilteredFirstDifference
from manus.plants.simulator import Encoder

THESIS_CORNER = FilteredFirstDifference().corner  # λ = 188.5 rad/s, the thesis's 30 Hz (eq. 3.19)
THESIS_STEP = Encoder().step  # Δ = 2π/131072 rad, the thesis's encoder (§2.6)


def quantization_variance(step: float = THESIS_STEP) -> float:
    """R = Δ²/12: the variance of rounding to a grid of step Δ (uniform error in ±Δ/2)."""
    return step * step / 12


def ffd_noise_gain(dt: float, corner: float = THESIS_CORNER) -> float:
    """√Σh² of the filtered first difference from position to velocity [1/s]: √(2β²/(1 + α))."""
    a, b = FilteredFirstDifference(dt=dt, corner=corner).coefficients
    return float(np.sqrt(2 * b * b / (1 + a)))


def velocity_noise_gain(A: np.ndarray, K: np.ndarray, dt: float) -> float:
    """√Σh² from the measurement to the velocity (state 1) of x_k = A x_{k−1} + K y_k, states
    (q, q̇, ...). Solved in the scaled states T^i x_i, all in position units (well conditioned)."""
    s = dt ** np.arange(len(K))
    X = scipy.linalg.solve_discrete_lyapunov(A * s[:, None] / s[None, :], np.outer(K * s, K * s))
    return float(np.sqrt(X[1, 1]) / dt)


def equal_noise_bandwidth(
    design: Callable[[float], tuple[np.ndarray, np.ndarray]], dt: float, corner: float = THESIS_CORNER
) -> float:
    """The bandwidth ω [rad/s] at which `design(ω) -> (A, K)` has the velocity noise gain of the
    thesis's filtered first difference (the gain grows with ω: a bracketed root on log ω)."""
    target = np.log(ffd_noise_gain(dt, corner))
    f = lambda lw: np.log(velocity_noise_gain(*design(np.exp(lw)), dt)) - target
    lo, hi = np.log(1.0), np.log(0.9 * np.pi / dt)
    if not f(lo) < 0 < f(hi):
        raise ValueError(
            f"no bandwidth between 1 rad/s and 0.9 Nyquist ({0.45 / dt:.4g} Hz) has the velocity noise of "
            f"the {corner / (2 * np.pi):.4g} Hz filtered first difference at {1 / dt:.4g} Hz"
            + (" (its corner is above Nyquist: raise the rate)" if corner >= np.pi / dt else "")
        )
    root: float = scipy.optimize.brentq(f, lo, hi, xtol=1e-8)  # pyright: ignore[reportAssignmentType]
    return float(np.exp(root))
