"""Offline (zero-phase) differentiation of a whole recording.

Used by `manus fit` (inverse-dynamics identification needs q̇ and q̈ without phase lag) and as the
reference that causal estimators are scored against when a recording has no true velocity.

The positions are low-pass filtered forward and backward (a Butterworth filter run with
`filtfilt`: zero phase, squared magnitude) and differentiated by central differences. The same
`lowpass` is available for the torque: identification filters τ and the regressor alike, so a
linear model stays exact after filtering (the EMPS reference procedure: low-pass at 100 Hz,
central differences).
"""

from __future__ import annotations

import numpy as np
from scipy import signal


def lowpass(x: np.ndarray, dt: float, cutoff_hz: float, order: int = 4) -> np.ndarray:
    """Zero-phase Butterworth low-pass along axis 0 (no filtering when cutoff ≥ Nyquist)."""
    x = np.asarray(x, float)
    nyquist = 0.5 / dt
    if cutoff_hz >= nyquist:
        return x.copy()
    sos = signal.butter(order, cutoff_hz / nyquist, output="sos")
    pad = min(x.shape[0] - 1, 3 * int(np.ceil(1 / (cutoff_hz * dt))))
    return signal.sosfiltfilt(sos, x, axis=0, padtype="odd", padlen=pad)


def differentiate(q: np.ndarray, dt: float, cutoff_hz: float = 30.0, order: int = 4):
    """(q, q̇, q̈) of positions q (T,) or (T, n): zero-phase low-pass at `cutoff_hz`, then
    central differences (one-sided at the ends)."""
    qf = lowpass(q, dt, cutoff_hz, order)
    qd = np.gradient(qf, dt, axis=0)
    qdd = np.gradient(qd, dt, axis=0)
    return qf, qd, qdd


def edge(dt: float, cutoff_hz: float) -> int:
    """Samples at each end where the filter's start-up transient lives: drop them when fitting."""
    return int(np.ceil(3.0 / (cutoff_hz * dt)))
