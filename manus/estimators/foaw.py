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
import numpy as np
from jax import Array

from manus.estimators.base import Estimate, Estimator
from manus.estimators.linear import THESIS_STEP


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

    def slopes(self) -> np.ndarray:
        """W (N+1, N) with b_n = Σᵢ W[i, n−1] y_{k−i}: the least-squares slopes as one product."""
        i, n = np.arange(self.window + 1.0)[:, None], np.arange(1.0, self.window + 1)
        return np.where(i <= n, (n - 2 * i) / (self.dt * n * (n + 1) * (n + 2) / 6), 0.0)

    def step(self, state, q, tau=None):
        y = jnp.concatenate([q[..., None], state[..., :-1]], axis=-1)  # y[..., i] = y_{k−i}
        N = self.window
        dy = y - y[..., :1]  # relative to y_k: the same slopes, exactly 0 at rest, no cancellation
        b = dy @ self.slopes()  # (..., N): the slope of window n
        n, j = np.arange(1, N + 1), np.arange(1, N)  # windows, and the samples in between
        miss = jnp.abs(dy[..., None, 1:N] + b[..., :, None] * j * self.dt)  # |y_{k−j} − (y_k − b_n j T)|
        ok = jnp.all((miss <= self.d) | (j >= n[:, None]), axis=-1)  # (..., N); n = 1 always
        longest = jnp.where(jnp.all(ok, -1), N, jnp.argmin(ok, -1))  # windows before the first failure
        v = jnp.take_along_axis(b, (longest - 1)[..., None], -1)[..., 0]
        return y, Estimate(q, v)
