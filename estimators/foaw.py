"""First-order adaptive windowing (`foaw`): the slope over the longest recent window in which a
straight line explains every sample to within the noise.

F. Janabi-Sharifi, V. Hayward, C.-S. J. Chen, "Discrete-time adaptive windowing for velocity
estimation", IEEE Trans. Control Syst. Technol. 8(6):1003–1009, 2000 (the best-fit variant).
Made for position encoders: when the motion is slow the window grows (many samples average the
quantization away), when it is fast or changes the window shrinks (little lag).

At sample k, for n = 1, 2, …, N: the least-squares slope over the n + 1 newest samples

    b_n = (n Σᵢ y_{k−i} − 2 Σᵢ i y_{k−i}) / (T n(n+1)(n+2)/6),   i = 0..n

is accepted while the line through y_k with that slope passes within `d` of every sample in
between, |y_{k−j} − (y_k − b_n j T)| ≤ d for 0 < j < n. The estimate is the slope of the longest
window accepted without a failure before it (n = 1, the first difference, always is).

`d` [position] is the noise band (the knob); an encoder of step Δ has errors within ±Δ/2, so two
samples differ by up to Δ from the line: default d = Δ. `window` N is the longest window
(default 30 samples, 30 ms at 1 kHz); the history starts filled with the first sample (at rest).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jax import Array

from estimators.base import Estimate, Estimator
from estimators.linear import THESIS_STEP


class Foaw(Estimator):
    """Best-fit first-order adaptive windowing; state: the last N + 1 positions, newest first."""

    dt: float = eqx.field(static=True)
    window: int = eqx.field(static=True)
    d: Array

    def __init__(self, dt: float = 1e-3, d: float = THESIS_STEP, window: int = 30):
        if not d > 0 or window < 1:
            raise ValueError(f"FOAW needs a positive noise band d and a window ≥ 1, got d={d:g}, window={window}")
        self.dt, self.window, self.d = float(dt), int(window), jnp.asarray(float(d))

    def init(self, q0):
        q0 = jnp.asarray(q0, float)
        return jnp.broadcast_to(q0[..., None], q0.shape + (self.window + 1,))

    def step(self, state, q, tau=None):
        y = jnp.concatenate([q[..., None], state[..., :-1]], axis=-1)  # y[..., i] = y_{k−i}
        N = self.window
        i = jnp.arange(N + 1.0)
        n = i[1:]
        dy = y - y[..., :1]  # relative to y_k: the same slopes, exactly 0 at rest, no cancellation
        s0 = jnp.cumsum(dy, -1)[..., 1:]  # Σ_{i≤n} (y_{k−i} − y_k)
        s1 = jnp.cumsum(i * dy, -1)[..., 1:]  # Σ_{i≤n} i (y_{k−i} − y_k)
        b = (n * s0 - 2 * s1) / (self.dt * n * (n + 1) * (n + 2) / 6)  # (..., N): slope of window n
        j = i[1:N]  # the samples in between
        miss = jnp.abs(dy[..., None, 1:N] + b[..., :, None] * j * self.dt)  # |y_{k−j} − (y_k − b_n j T)|, (..., n, j)
        ok = jnp.all((miss <= self.d) | (j >= n[:, None]), axis=-1)  # (..., N)
        longest = jnp.sum(jnp.cumprod(ok, axis=-1), axis=-1)  # ≥ 1: n = 1 has nothing in between
        v = jnp.take_along_axis(b, (longest - 1)[..., None].astype(int), -1)[..., 0]
        return y, Estimate(q, v)
