"""How good a velocity estimate is: error while moving and while still, lag, noise, whiteness.

All functions take numpy arrays (T, n) and return plain floats. `reference` is the true velocity
when a recording has one, else the offline zero-phase estimate (`manus.estimators.offline`).

- **error**: estimate − reference; RMS and max over all joints, also separately over the samples
  where the reference moves and where it holds still (|reference| under `still_threshold`).
- **lag**: the shift that maximises the cross-correlation of the estimate with the reference,
  refined between samples by a parabola through the peak; positive = the estimate is late. None
  when the peak lies at the end of the ±50 ms searched (no lag explains the estimate).
- **noise above 50 Hz**: RMS of the error after a zero-phase 4th-order Butterworth high-pass at
  50 Hz (human motion has nothing there; what is left is noise and the estimator's artefacts).
- **whiteness**: for tuning without a true velocity. The estimator's one-step prediction of the
  next measurement, q̂ + T q̂̇ (+ ½T² q̂̈), leaves the residual ε_k = q_k − prediction (for a Kalman
  filter, its innovation). A well-tuned estimator leaves nothing predictable in it: the statistic
  is Σ_l ρ_l² over lags l = 1..20 of its autocorrelation ρ (the Box–Pierce statistic / N).
  Too sluggish an estimator leaves the motion in ε (ρ ≈ 1); too nervous a one passes quantization
  noise through its differences (ρ₁ strongly negative).
"""

from __future__ import annotations

import numpy as np
from scipy import signal

NOISE_CUTOFF_HZ = 50.0
STILL_FRACTION = 0.02  # holding still: |q̇| below 2 % of the joint's 99th-percentile speed
WHITENESS_LAGS = 20


def rms(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def peak(x) -> float:
    x = np.asarray(x, float)
    return float(np.max(np.abs(x))) if x.size else float("nan")


def still_threshold(reference: np.ndarray) -> np.ndarray:
    """Per joint: the speed under which a joint counts as holding still."""
    return STILL_FRACTION * np.percentile(np.abs(reference), 99, axis=0)


def lag_seconds(estimate: np.ndarray, reference: np.ndarray, dt: float, max_lag: float = 0.05) -> float | None:
    """Delay of `estimate` behind `reference` [s] by cross-correlation (all joints together)."""
    m = int(round(max_lag / dt))
    n = len(reference)
    c = np.asarray(
        sum(
            signal.correlate(estimate[:, j], reference[:, j], mode="full", method="fft")[n - 1 - m : n + m]
            for j in range(reference.shape[1])
        )
    )  # c[m + s] = Σ_k est[k + s] ref[k]
    k = int(np.argmax(c))
    if not 0 < k < 2 * m:
        return None
    y0, y1, y2 = c[k - 1], c[k], c[k + 1]
    den = y0 - 2 * y1 + y2
    return (k - m + (0.5 * (y0 - y2) / den if den != 0 else 0.0)) * dt


def highpass_rms(x: np.ndarray, dt: float, cutoff_hz: float = NOISE_CUTOFF_HZ) -> float | None:
    """RMS of x above `cutoff_hz` (None when that is above the Nyquist frequency)."""
    nyquist = 0.5 / dt
    if cutoff_hz >= nyquist or len(x) < 30:
        return None
    sos = signal.butter(4, cutoff_hz / nyquist, btype="high", output="sos")
    return rms(signal.sosfiltfilt(sos, x, axis=0))


def score(estimate: np.ndarray, reference: np.ndarray, dt: float, still: np.ndarray) -> dict:
    """The report of one estimate (T, n) against a reference (T, n); `still` (T, n) marks the
    samples where the reference holds still."""
    err = estimate - reference
    lag = lag_seconds(estimate, reference, dt)
    part = lambda mask: {"rms_error": rms(err[mask]), "max_error": peak(err[mask]), "fraction": float(mask.mean())}
    return {
        "rms_error": rms(err),
        "max_error": peak(err),
        "rms_error_per_joint": [rms(err[:, j]) for j in range(err.shape[1])],
        "moving": part(~still),
        "still": part(still),
        "lag_ms": None if lag is None else 1e3 * lag,
        "noise_50hz": highpass_rms(err, dt),
    }


def prediction_residual(
    q: np.ndarray, q_hat: np.ndarray, qd_hat: np.ndarray, qdd_hat: np.ndarray | None, dt: float
) -> np.ndarray:
    """ε_k = q_k − (q̂_{k−1} + T q̂̇_{k−1} + ½T² q̂̈_{k−1}), shape (T − 1, n); arrays may carry
    leading batch axes."""
    pred = q_hat + dt * qd_hat + (0.0 if qdd_hat is None else 0.5 * dt * dt * qdd_hat)
    return q[..., 1:, :] - pred[..., :-1, :]


def whiteness(residual: np.ndarray, lags: int = WHITENESS_LAGS) -> np.ndarray:
    """Σ_l ρ_l², l = 1..lags, summed over joints, of residuals (..., T, n) (0 for white noise)."""
    x = residual - residual.mean(axis=-2, keepdims=True)
    c0 = np.sum(x * x, axis=-2)
    c0 = np.where(c0 > 0, c0, 1.0)  # a residual identically zero is (trivially) white
    rho = np.stack([np.sum(x[..., l:, :] * x[..., :-l, :], axis=-2) / c0 for l in range(1, lags + 1)])
    return np.sum(rho * rho, axis=(0, -1))
