"""Search of a model's non-linear parameters (the cogging order, the Stribeck velocity, the
delay) for `manus.adaptive.fit`: a grid of least-squares fits, each cheap because the columns that do
not change are projected out once (`Projection`)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from manus.plants.effects import Cogging, Delay, Effect, Model, Stribeck
from manus.plants.errors import ModelError

if TYPE_CHECKING:
    from manus.adaptive.fit import Columns, Data


class Projection:
    """Least squares with a fixed set of columns done once (QR), so that adding a few columns
    or changing the target costs little: what a grid search needs."""

    def __init__(self, Y: np.ndarray):
        rows, n, P = Y.shape
        X = Y.reshape(rows * n, P)
        self.shape = (rows, n)
        self.Q = np.linalg.qr(X / (np.sqrt(np.mean(X**2, axis=0)) + 1e-300))[0] if P else np.zeros((rows * n, 0))

    # The products below are tall and thin (rows × a few columns): einsum's own loops, not BLAS,
    # whose threads on a busy 2-core machine spin-wait far longer than these take (20x slower).
    def _perp(self, x):
        return x - np.einsum("ij,j...->i...", self.Q, np.einsum("ij,i...->j...", self.Q, x))

    def target(self, tau: np.ndarray) -> tuple:
        """The torque's part outside the fixed columns and its norm², for many `rel_error` calls."""
        y = tau.reshape(-1)
        return y, self._perp(y), float(np.einsum("i,i->", y, y))

    def rel_error(self, tau: np.ndarray | tuple, extra: np.ndarray | None = None) -> float:
        y, r, yy = tau if isinstance(tau, tuple) else self.target(tau)
        if extra is not None and extra.size:
            E = self._perp(extra.reshape(y.size, -1))
            coef = np.linalg.lstsq(np.einsum("ij,ik->jk", E, E), np.einsum("ij,i->j", E, r), rcond=1e-12)[0]
            r = r - np.einsum("ij,j->i", E, coef)
        return float(np.sqrt(np.einsum("i,i->", r, r) / yy))


def search(data: Data, cols: Columns, model: Model, e: Effect):
    """Grid search (then local refinement) of one effect's non-linear parameter, the others
    held: each grid point is a least-squares fit of the model with that value."""
    rest = model.without(e.name)
    delay = rest.get("delay").seconds if rest.has("delay") else 0.0
    if isinstance(e, Delay):
        proj = Projection(cols.model(rest))
        grid = np.arange(0.0, 5.01e-3, 0.1e-3)
        errs = np.array([proj.rel_error(data.tau(x)) for x in grid])
        best = grid[int(np.argmin(errs))]
        i = int(np.argmin(errs))
        if 0 < i < len(grid) - 1:  # sub-grid: a parabola through the best three
            a, b, c = errs[i - 1:i + 2]
            if a - 2 * b + c > 0:
                best = grid[i] + 0.5 * (a - c) / (a - 2 * b + c) * (grid[1] - grid[0])
        return model.with_effect(Delay(seconds=round(float(best) * 1e5) / 1e5)), (grid, errs)
    proj = Projection(cols.model(rest))
    tau = data.tau(delay)
    if isinstance(e, Cogging):
        grid = cogging_grid(data)
        # screen on unfiltered columns (sin(Nq) lies far below the cut-off at these speeds),
        # then evaluate the best few exactly
        q = data.q[data.rows]
        target = proj.target(tau)
        screen = np.array([proj.rel_error(target, np.concatenate([np.sin(N * q)[..., None] * np.eye(q.shape[1]),
                                                                 np.cos(N * q)[..., None] * np.eye(q.shape[1])], 2))
                           for N in grid])
        errs = screen.copy()
        for i in np.argsort(screen)[:3]:
            errs[i] = proj.rel_error(target, cols.effect(Cogging(order=float(grid[i]))))
        return model.with_effect(Cogging(order=float(grid[int(np.argmin(errs))]))), (grid, errs)
    if isinstance(e, Stribeck):
        vmax = float(np.percentile(np.abs(data.qd[data.rows]), 95))
        grid = np.geomspace(max(vmax * 1e-3, 1e-9), vmax, 25)
        target = proj.target(tau)
        errs = np.array([proj.rel_error(target, cols.effect(Stribeck(vs=float(x)))) for x in grid])
        return model.with_effect(Stribeck(vs=float(grid[int(np.argmin(errs))]))), (grid, errs)
    raise ModelError(f"no search for effect {e.name!r}")


def cogging_grid(data: Data) -> np.ndarray:
    """Orders N (sin(N q)) worth trying: integer cycles per revolution for rotary joints, from 2
    (N = 1 is the gravity term's shape) up to where one period spans about 40 encoder counts; for
    prismatic axes a log grid over periods from the position range down to 40 counts."""
    if data.rec.structure_name == "manus2" or data.rec.counts_per_rev:
        top = 200 if not data.step else min(200, int(2 * np.pi / (40 * data.step)))
        return np.arange(2, max(top, 3) + 1, dtype=float)
    span = float(np.ptp(data.q[data.rows], axis=0).max())
    fine = 40 * max(data.step, span * 1e-5)
    return np.geomspace(2 * np.pi / span, 2 * np.pi / fine, 200)


