"""Frequency response of a velocity estimator, measured (thesis Fig. 3-25).

Each estimator is fed sampled sinusoids q = A sin(2π f t), one frequency per column (the
estimators work per joint, so one scan measures every frequency), and its velocity estimate is
fitted, over the second half of the run, by a sinusoid at the same frequency. The response is

    H(f) = (estimated velocity phasor) / (true velocity phasor 2π f A · j)

so |H| = 1 and ∠H = 0 mean a perfect estimate; −∠H is the phase lag behind the true velocity
[rad]. For a linear estimator this is its transfer function from q̇ to q̂̇ exactly (after the
transient). For the non-linear ones (Levant, FOAW) it is the describing function at amplitude A.
The model-based ones get the torque their own model needs for the motion (the model's inverse
dynamics, with its friction boundary layer), i.e. their response when the model is right.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from manus.estimators.base import run
from manus.estimators.registry import MODEL_BASED, make

_run_each = eqx.filter_jit(eqx.filter_vmap(run, in_axes=(None, 0, 0)))  # one joint, many signals


def sinusoids(freqs_hz: np.ndarray, dt: float, seconds: float, amplitude: float) -> tuple[np.ndarray, np.ndarray]:
    """(t (T,), q (T, F)): one sinusoid per column, starting at rest position 0 with phase 0."""
    t = np.arange(int(round(seconds / dt))) * dt
    return t, amplitude * np.sin(2 * np.pi * np.outer(t, freqs_hz))


def phasor(x: np.ndarray, t: np.ndarray, freqs_hz: np.ndarray) -> np.ndarray:
    """Per column, the complex amplitude P of x ≈ Re(P e^{jωt}) + offset (least squares)."""
    out = np.empty(len(freqs_hz), complex)
    for i, f in enumerate(freqs_hz):
        w = 2 * np.pi * f
        (a, b, _), *_ = np.linalg.lstsq(
            np.stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)], 1), x[:, i], rcond=None
        )
        out[i] = a - 1j * b
    return out


def frequency_response(
    name: str, freqs_hz, dt: float = 1e-3, amplitude: float = 0.01, seconds: float | None = None, **knobs
) -> np.ndarray:
    """H(f) (complex, per frequency) of estimator `name` built by `make(name, dt, **knobs)` for
    one joint (an axis for the model-based ones) and run on every frequency at once (vmapped);
    `seconds` defaults to four periods of the lowest frequency."""
    freqs_hz = np.asarray(freqs_hz, float)
    duration = max(4.0 / float(freqs_hz.min()), 1.0) if seconds is None else seconds
    t, q = sinusoids(freqs_hz, dt, duration, amplitude)
    estimator = make(name, dt=dt, n_joints=1, **({"structure": "axis", **knobs} if name in MODEL_BASED else knobs))
    tau = np.zeros_like(q)
    if name in MODEL_BASED:  # the command of sample k acts over [t_k, t_k + T]: its torque at the middle
        tau = _inverse_dynamics(estimator, t + 0.5 * dt, freqs_hz, amplitude)
    out = _run_each(estimator, jnp.asarray(q.T[..., None]), jnp.asarray(tau.T[..., None]))
    qd = np.asarray(out.qd)[..., 0].T
    half = len(t) // 2
    return phasor(qd[half:], t[half:], freqs_hz) / (2 * np.pi * freqs_hz * amplitude)  # q̇ = Aω cos ωt


def _inverse_dynamics(estimator, t, freqs_hz, amplitude):
    """τ (T, F): the torque the estimator's own one-joint model needs for q = A sin(ωt)."""
    dynamics = estimator.dynamics
    model, p, boundary = dynamics.model, dynamics.model.unvector(estimator.theta0), dynamics.boundary
    w = 2 * np.pi * freqs_hz
    s, c = np.sin(np.outer(t, w)), np.cos(np.outer(t, w))
    x = [jnp.asarray(a.reshape(-1, 1)) for a in (amplitude * s, amplitude * w * c, -amplitude * w * w * s)]
    torque = jax.jit(jax.vmap(lambda a, b, d: model.torque(a, b, d, p, boundary=boundary)))
    return np.asarray(torque(*x)).reshape(s.shape)
