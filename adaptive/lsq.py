"""The one least-squares core of identification: τ ≈ X θ over rows and joints, by ordinary least
squares (IDIM-LS) or with instruments (IDIM-IV), on any set of contiguous row segments.

Everything `fit`, the parameter search and `diagnose` need comes from per-segment sufficient
statistics (`Stats`): XᵀX, Xᵀτ, τᵀτ (and ZᵀX, Zᵀτ with instruments Z) summed over each segment of
rows once. A fit on any union of segments is then a P×P solve, and its squared error on any
other union is a quadratic form: a grid search inside each held-out fold costs little more
than one fit. The products over rows are `np.add.reduceat` of element-wise products (no BLAS:
on a busy 2-core machine BLAS threads spin-wait far longer than these tall, thin products take).

`solve` is the full fit on every row, with what a report needs: redundant columns named (those
the earlier ones explain: the regressor's rank deficiency), each parameter's standard deviation
from a heteroscedasticity- and autocorrelation-consistent (Newey–West) covariance, the residual.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

RCOND = 1e-10


def _flat(X: np.ndarray) -> np.ndarray:
    rows, n = X.shape[:2]
    return X.reshape(rows * n, -1) if X.ndim == 3 else X.reshape(rows * n)


class Stats:
    """Per-segment sums of τ ≈ X θ. X (rows, n, P), tau (rows, n), `starts` the first row of each
    segment (sorted, starting at 0); Z (rows, n, P) instruments or None (least squares)."""

    def __init__(self, X: np.ndarray, tau: np.ndarray, starts: np.ndarray, Z: np.ndarray | None = None):
        self.starts = np.asarray(starts, int)
        self.scale = np.sqrt(np.mean(X**2, axis=(0, 1))) + 1e-300
        self.X = X / self.scale
        self.Z = None if Z is None else Z / (np.sqrt(np.mean(Z**2, axis=(0, 1))) + 1e-300)
        self.iv = Z is not None
        self.G = self._sum(np.einsum("rnp,rnq->rpq", self.X, self.X))
        self.target(tau)

    def _sum(self, per_row: np.ndarray) -> np.ndarray:
        return np.add.reduceat(per_row, self.starts, axis=0)

    def target(self, tau: np.ndarray) -> "Stats":
        """Another torque for the same columns (a delay searched: the torque moves, X stays)."""
        self.tau = tau
        self.g = self._sum(np.einsum("rnp,rn->rp", self.X, tau))
        self.yy = self._sum(np.einsum("rn,rn->r", tau, tau))
        if self.iv:
            self.H = self._sum(np.einsum("rnp,rnq->rpq", self.Z, self.X))
            self.h = self._sum(np.einsum("rnp,rn->rp", self.Z, tau))
        return self

    def extend(self, E: np.ndarray, Ez: np.ndarray | None = None) -> "Stats":
        """These statistics with the columns E (rows, n, k) appended (instruments Ez), reusing
        the sums of the columns already here: what a grid search over an effect's non-linear
        parameter needs per grid point."""
        new = object.__new__(Stats)
        new.starts = self.starts
        sE = np.sqrt(np.mean(E**2, axis=(0, 1))) + 1e-300
        Es = E / sE
        new.scale = np.r_[self.scale, sE]
        XE = self._sum(np.einsum("rnp,rnq->rpq", self.X, Es))
        EE = self._sum(np.einsum("rnp,rnq->rpq", Es, Es))
        new.G = np.concatenate([np.concatenate([self.G, XE], 2),
                                np.concatenate([XE.transpose(0, 2, 1), EE], 2)], 1)
        new.g = np.concatenate([self.g, self._sum(np.einsum("rnp,rn->rp", Es, self.tau))], 1)
        # (the rows themselves are not kept: an extended Stats is a grid point, not extended again)
        new.yy, new.tau, new.X, new.Z, new.iv = self.yy, self.tau, None, None, False
        if self.iv and Ez is not None:
            Zs = Ez / (np.sqrt(np.mean(Ez**2, axis=(0, 1))) + 1e-300)
            ZE = self._sum(np.einsum("rnp,rnq->rpq", self.Z, Es))  # old instruments × new columns
            EX = self._sum(np.einsum("rnp,rnq->rpq", Zs, self.X))  # new instruments × old columns
            EEz = self._sum(np.einsum("rnp,rnq->rpq", Zs, Es))
            new.H = np.concatenate([np.concatenate([self.H, ZE], 2), np.concatenate([EX, EEz], 2)], 1)
            new.h = np.concatenate([self.h, self._sum(np.einsum("rnp,rn->rp", Zs, self.tau))], 1)
            new.iv = True
        return new

    def coef(self, use: np.ndarray) -> np.ndarray:
        """Scaled coefficients fitted on the segments `use` (bool mask): minimum-norm least
        squares, or the instrumental-variable solution when instruments were given."""
        if not self.iv:
            A, b = self.G[use].sum(0), self.g[use].sum(0)
        else:
            A, b = self.H[use].sum(0), self.h[use].sum(0)
        return np.linalg.lstsq(A, b, rcond=RCOND)[0]

    def coefs(self, masks: np.ndarray) -> np.ndarray:
        """`coef` on each of the segment masks (F, S) at once: (F, P), one batched pseudo-inverse
        (the same minimum-norm solution as `coef`'s, to rounding)."""
        A, b = (self.H, self.h) if self.iv else (self.G, self.g)
        m = np.asarray(masks, float)
        return np.einsum("fpq,fq->fp", np.linalg.pinv(np.einsum("fs,spq->fpq", m, A), rcond=RCOND), m @ b)

    def sses(self, C: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """Squared error of the coefficients C (F, P) on the segments of each mask (F, S), summed
        per mask: (F,), as `sse(...).sum()` row by row."""
        quad = np.einsum("fsp,fp->fs", np.einsum("spq,fq->fsp", self.G, C), C)
        per = np.maximum(self.yy[None, :] - 2 * C @ self.g.T + quad, 0.0)
        return (per * masks).sum(1)

    def sse(self, c: np.ndarray, use: np.ndarray) -> np.ndarray:
        """Squared error of scaled coefficients `c` on each segment of `use`."""
        # (a quadratic form: clipped at 0 where rounding leaves an exact fit slightly negative)
        return np.maximum(self.yy[use] - 2 * self.g[use] @ c + np.einsum("p,spq,q->s", c, self.G[use], c), 0.0)

    def theta(self, c: np.ndarray) -> np.ndarray:
        return c / self.scale


def folds(rows: np.ndarray, k: int, guard: int) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """`k` contiguous held-out blocks over the used rows (sample indices `rows`, sorted), each
    holding about the same number of rows (a recording with rests has its rows in clusters), with
    a guard of `guard` samples at its seams left out of the training set (the filtered residual
    is correlated over about one filter length). Returns the segment starts (row positions) and,
    per block, (train, test) masks over the segments."""
    first = np.linspace(0, rows.size, k + 1).round().astype(int)  # row positions where blocks start
    cuts = []
    for a, b in zip(first[:-1], first[1:]):
        if b <= a:
            continue
        t0, t1 = rows[a], rows[b - 1] + 1
        cuts += [a, int(np.searchsorted(rows, t0 + guard)), int(np.searchsorted(rows, t1 - guard))]
    cuts = np.unique(np.clip(cuts, 0, rows.size - 1))
    block = np.searchsorted(first, cuts, side="right") - 1  # the block of each segment
    seg_t = rows[cuts]
    seg_end = np.r_[rows[cuts[1:] - 1], rows[-1]]
    out = []
    for j in range(k):
        test = block == j
        if not test.any():
            continue
        lo, hi = seg_t[test].min() - guard, seg_end[test].max() + guard
        near = (seg_end >= lo) & (seg_t < hi)
        out.append((~test & ~near, test))
    return cuts, out


@dataclass
class Solution:
    theta: np.ndarray  # (P,)
    std: np.ndarray  # (P,)
    redundant: list[int]  # columns the others already explain (their θ is 0)
    residual: np.ndarray  # (rows, n)
    rel_error: float


def unidentifiable(Y: np.ndarray, rtol: float = 1e-7) -> list[int]:
    """Columns of Y (rows, n, P) that are zero or that the earlier ones explain (the regressor's
    rank deficiency, in column order); every column when there are fewer equations than the rank
    would need."""
    rows, n, P = Y.shape
    if rows * n == 0:
        return list(range(P))
    X = _flat(Y)
    scale = np.sqrt(np.mean(X**2, axis=0))
    out = [j for j in range(P) if not scale[j] > 0]
    keep = [j for j in range(P) if scale[j] > 0]
    if keep:
        r = np.abs(np.diag(np.linalg.qr(X[:, keep] / scale[keep], mode="r")))
        r = np.r_[r, np.zeros(len(keep) - r.size)]  # fewer equations than columns: the rest are lost
        out += [keep[j] for j in np.flatnonzero(r < rtol * max(r.max(initial=0), 1e-300) * np.sqrt(rows * n))]
    return sorted(out)


def solve(Y: np.ndarray, tau: np.ndarray, Z: np.ndarray | None = None, rtol: float = 1e-7,
          hac_lags: int = 5) -> Solution:
    """τ ≈ Y θ over all rows and joints: least squares, or instrumental variables with Z (same
    shape as Y). Y (rows, n, P), tau (rows, n)."""
    rows, n, P = Y.shape
    X, y = _flat(Y), _flat(tau)
    redundant = unidentifiable(Y, rtol)
    keep = [j for j in range(P) if j not in redundant]
    theta, std = np.zeros(P), np.full(P, np.nan)
    if keep:
        scale = np.sqrt(np.mean(X[:, keep] ** 2, axis=0))
        Xk = X[:, keep] / scale
        W = Xk if Z is None else _flat(Z)[:, keep] / (np.sqrt(np.mean(_flat(Z)[:, keep] ** 2, axis=0)) + 1e-300)
        A = np.einsum("ip,iq->pq", W, Xk)
        coef = np.linalg.lstsq(A, np.einsum("ip,i->p", W, y), rcond=RCOND)[0]
        theta[keep] = coef / scale
        e = y - Xk @ coef
        cov = _newey_west(A, W, e, n, hac_lags)
        std[keep] = np.sqrt(np.maximum(np.diag(cov), 0)) / scale
    resid = (y - X @ theta).reshape(rows, n)
    denom = np.linalg.norm(y)
    return Solution(theta, std, sorted(redundant), resid, float(np.linalg.norm(resid) / denom) if denom else np.inf)


def _newey_west(A: np.ndarray, W: np.ndarray, e: np.ndarray, n: int, lags: int) -> np.ndarray:
    """Covariance of θ = A⁻¹ Wᵀy (A = WᵀX; W = X for least squares) robust to unequal noise per
    joint and to residual autocorrelation over `lags` rows (Bartlett weights). Rows are
    interleaved by joint."""
    A_inv = np.linalg.pinv(A)
    g = W * e[:, None]  # score per row
    meat = g.T @ g
    for lag in range(1, lags + 1):
        w = 1 - lag / (lags + 1)
        a, b = g[lag * n:], g[:-lag * n]  # the same joint, `lag` rows apart
        meat += w * (a.T @ b + b.T @ a)
    return A_inv @ meat @ A_inv.T


def one_sided_p(base_sse: np.ndarray, sse: np.ndarray) -> float:
    """p of 'the candidate predicts the held-out blocks better': a one-sided t-test over blocks
    on the log ratio of squared errors (scale-free: a loud block does not dominate)."""
    ok = (base_sse > 0) & (sse > 0)
    if ok.sum() < 3:
        return 1.0
    d = np.log(base_sse[ok] / sse[ok])
    sd = d.std(ddof=1)
    if not sd > 0:
        return 0.0 if d.mean() > 0 else 1.0
    return float(stats.t.sf(d.mean() / (sd / np.sqrt(d.size)), d.size - 1))
