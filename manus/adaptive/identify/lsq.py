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
`folds` cuts the rows into contiguous held-out blocks.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

RCOND = 1e-10


def _flat(X: np.ndarray) -> np.ndarray:
    rows, n = X.shape[:2]
    return X.reshape(rows * n, -1) if X.ndim == 3 else X.reshape(rows * n)


def _segments(per_row: np.ndarray, starts: np.ndarray, axis: int = 0) -> np.ndarray:
    """`per_row` summed over each segment (the rows from one start to the next) along `axis`."""
    return np.add.reduceat(per_row, starts, axis=axis)


@dataclass(frozen=True, eq=False)
class Stats:
    """Per-segment sums of τ ≈ X θ, the columns scaled to unit RMS (`scale`): G = XᵀX, g = Xᵀτ,
    yy = τᵀτ per segment (S, ...), and with instruments Z, H = ZᵀX and h = Zᵀτ (`iv`). Built from
    rows by `Stats.of`, which keeps the scaled rows (X, Z, tau) for `extend`; the statistics
    `extend` returns hold no rows (a grid point, not extended again). A batch of V values carries
    a leading axis V on G, g, scale (and H, h); `one(i)` is value i's."""

    starts: np.ndarray  # the first row of each segment (sorted, starting at 0)
    scale: np.ndarray  # (P,) each column's RMS over the rows
    G: np.ndarray  # (S, P, P)
    g: np.ndarray  # (S, P)
    yy: np.ndarray  # (S,)
    H: np.ndarray | None = None  # (S, P, P) with instruments, else None
    h: np.ndarray | None = None  # (S, P)
    X: np.ndarray | None = None  # (rows, n, P) the scaled columns
    Z: np.ndarray | None = None  # (rows, n, P) the scaled instruments
    tau: np.ndarray | None = None  # (rows, n)

    @classmethod
    def of(cls, X: np.ndarray, tau: np.ndarray, starts: np.ndarray, Z: np.ndarray | None = None) -> Stats:
        """The statistics of X (rows, n, P), tau (rows, n) over the segments starting at `starts`;
        Z (rows, n, P) instruments or None (least squares)."""
        starts = np.asarray(starts, int)
        scale = np.sqrt(np.mean(X**2, axis=(0, 1))) + 1e-300
        X = X / scale
        Z = None if Z is None else Z / (np.sqrt(np.mean(Z**2, axis=(0, 1))) + 1e-300)
        G = _segments(np.einsum("rnp,rnq->rpq", X, X), starts)
        g = _segments(np.einsum("rnp,rn->rp", X, tau), starts)
        yy = _segments(np.einsum("rn,rn->r", tau, tau), starts)
        H = h = None
        if Z is not None:
            H = _segments(np.einsum("rnp,rnq->rpq", Z, X), starts)
            h = _segments(np.einsum("rnp,rn->rp", Z, tau), starts)
        return cls(starts, scale, G, g, yy, H, h, X, Z, tau)

    @property
    def iv(self) -> bool:
        """Instrumental variables (else least squares)."""
        return self.H is not None

    def normal(self) -> tuple[np.ndarray, np.ndarray]:
        """The per-segment normal equations (A, b): (H, h) with instruments, else (G, g)."""
        if self.H is not None and self.h is not None:
            return self.H, self.h
        return self.G, self.g

    def extend(
        self,
        E: np.ndarray | Sequence[np.ndarray],
        Ez: np.ndarray | Sequence[np.ndarray] | None = None,
        budget: float = 8e6,
    ) -> Stats:
        """These statistics with the columns E (rows, n, k) appended (instruments Ez), reusing
        the sums of the columns already here: what a grid search over an effect's non-linear
        parameter needs per grid point. E (V, rows, n, k): V sets of columns, each appended on
        its own (a grid's values at once; or a list of V arrays (rows, n, k), stacked a chunk at a
        time): statistics with a leading axis V (`one(i)` is value i's), worked out `budget`
        floats of products at a time. Without `Ez`, the result is least squares."""
        X, tau = self.X, self.tau
        assert X is not None and tau is not None, "extended statistics hold no rows: they are not extended again"
        if isinstance(E, (list, tuple)) or (np.ndim(E) == 4):
            rows, k = np.shape(E[0])[0], np.shape(E[0])[-1]
            step = int(max(1, budget // max(rows * (X.shape[2] + k) * k, 1)))
            if isinstance(E, (list, tuple)) or len(E) > step:
                parts = [
                    self.extend(
                        np.stack(list(E[i : i + step])),
                        None if Ez is None else np.stack(list(Ez[i : i + step])),
                        budget,
                    )
                    for i in range(0, len(E), step)
                ]
                return parts[0] if len(parts) == 1 else _stacked(parts)
        E = np.asarray(E)
        ax = E.ndim - 3  # the rows' axis
        sE = np.sqrt(np.mean(E**2, axis=(-3, -2))) + 1e-300
        Es = E / sE[..., None, None, :]
        lead = E.shape[:ax]
        scale = np.concatenate([np.broadcast_to(self.scale, lead + self.scale.shape), sE], -1)
        XE = _segments(np.einsum("rnp,...rnq->...rpq", X, Es), self.starts, ax)
        EE = _segments(np.einsum("...rnp,...rnq->...rpq", Es, Es), self.starts, ax)
        G = _blocks(self.G, XE, np.swapaxes(XE, -1, -2), EE)
        g = np.concatenate(
            [
                np.broadcast_to(self.g, lead + self.g.shape),
                _segments(np.einsum("...rnp,rn->...rp", Es, tau), self.starts, ax),
            ],
            -1,
        )
        H = h = None
        if self.H is not None and self.h is not None and Ez is not None:
            assert self.Z is not None, "statistics with instruments keep their rows' instruments"
            Ez = np.asarray(Ez)
            Zs = Ez / (np.sqrt(np.mean(Ez**2, axis=(-3, -2))) + 1e-300)[..., None, None, :]
            # old instruments × new columns, new instruments × old columns, new × new
            ZE = _segments(np.einsum("rnp,...rnq->...rpq", self.Z, Es), self.starts, ax)
            EX = _segments(np.einsum("...rnp,rnq->...rpq", Zs, X), self.starts, ax)
            EEz = _segments(np.einsum("...rnp,...rnq->...rpq", Zs, Es), self.starts, ax)
            H = _blocks(self.H, ZE, EX, EEz)
            h = np.concatenate(
                [
                    np.broadcast_to(self.h, lead + self.h.shape),
                    _segments(np.einsum("...rnp,rn->...rp", Zs, tau), self.starts, ax),
                ],
                -1,
            )
        return Stats(self.starts, scale, G, g, self.yy, H, h)

    def one(self, i: int) -> Stats:
        """Value i's statistics of an `extend`ed batch (V sets of columns)."""
        return replace(
            self,
            G=self.G[i],
            g=self.g[i],
            scale=self.scale[i],
            H=None if self.H is None else self.H[i],
            h=None if self.h is None else self.h[i],
        )

    def coef(self, use: np.ndarray) -> np.ndarray:
        """Scaled coefficients fitted on the segments `use` (bool mask): minimum-norm least
        squares, or the instrumental-variable solution when instruments were given."""
        A, b = self.normal()
        return np.linalg.lstsq(A[use].sum(0), b[use].sum(0), rcond=RCOND)[0]

    def coefs(self, masks: np.ndarray, lower: np.ndarray | None = None) -> np.ndarray:
        """`coef` on each of the segment masks (F, S) at once: (F, P), one batched pseudo-inverse
        (the same minimum-norm solution as `coef`'s, to rounding); (V, F, P) for a batch of V
        values (`extend`). `lower` (P,): a lower bound per parameter (−inf: none); a coefficient
        that falls below its bound is held there and the others fitted again, until none does
        (an active set that only grows: exact where the bounded columns are nearly orthogonal,
        as per-joint friction columns are)."""
        A, b = self.normal()
        m = np.asarray(masks, float)
        M, r = _over_masks(m, A), m @ b
        C = self._solve(M, r)
        if lower is None or not np.isfinite(lower).any():
            return C
        low = np.where(np.isfinite(lower), lower * self.scale, -np.inf)[..., None, :]  # in the scaled units of C
        held = np.zeros(C.shape, bool)
        for _ in range(C.shape[-1]):
            more = (low > C) & ~held
            if not more.any():
                break
            held |= more
            x = np.where(held, low, 0.0)
            free = (~held).astype(float)
            r2 = (r - np.einsum("...pq,...q->...p", M, x)) * free
            C = np.where(held, low, self._solve(M * free[..., :, None] * free[..., None, :], r2))
        return C

    def _solve(self, M: np.ndarray, r: np.ndarray) -> np.ndarray:
        """Minimum-norm solutions of M c = r for a batch (..., P, P), (..., P)."""
        if self.iv:
            return np.einsum("...pq,...q->...p", np.linalg.pinv(M, rcond=RCOND), r)
        # least squares: M is symmetric, its pseudo-inverse from its eigenvectors (cheaper than an SVD)
        lam, U = np.linalg.eigh(M)
        keep = lam > RCOND * np.abs(lam).max(axis=-1, keepdims=True)
        inv = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
        return np.einsum("...pk,...k->...p", U, inv * np.einsum("...pk,...p->...k", U, r))

    def sses(self, C: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """Squared error of the coefficients C (F, P) on the segments of each mask (F, S), summed
        per mask: (F,); (V, F) for a batch (C (V, F, P))."""
        # (the sums over each mask's segments first: Σ_s m_s (yy_s − 2 cᵀg_s + cᵀG_s c) is one
        # quadratic form in the mask's G; clipped at 0 where rounding leaves an exact fit negative)
        m = np.asarray(masks, float)
        Gm = _over_masks(m, self.G)
        quad = np.einsum("...fp,...fpq,...fq->...f", C, Gm, C)
        return np.maximum(m @ self.yy - 2 * np.sum(C * (m @ self.g), -1) + quad, 0.0)

    def theta(self, c: np.ndarray) -> np.ndarray:
        """Scaled coefficients in the columns' own units."""
        return c / self.scale


def _over_masks(m: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Σ_s m_fs A_s for masks m (F, S) and per-segment matrices A (..., S, P, P): (..., F, P, P)."""
    P = A.shape[-1]
    return (m @ A.reshape(A.shape[:-2] + (P * P,))).reshape(A.shape[:-3] + (m.shape[0], P, P))


def _blocks(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> np.ndarray:
    """[[A, B], [C, D]] along the last two axes, A broadcast over the others' leading axes."""
    A = np.broadcast_to(A, B.shape[:-1] + A.shape[-1:])
    return np.concatenate([np.concatenate([A, B], -1), np.concatenate([C, D], -1)], -2)


def _stacked(parts: list[Stats]) -> Stats:
    """Batches of `Stats.extend` (leading axis V) joined into one."""
    first = parts[0]
    return replace(
        first,
        G=np.concatenate([p.G for p in parts]),
        g=np.concatenate([p.g for p in parts]),
        scale=np.concatenate([p.scale for p in parts]),
        H=None if first.H is None else np.concatenate([p.H for p in parts if p.H is not None]),
        h=None if first.h is None else np.concatenate([p.h for p in parts if p.h is not None]),
    )


def folds(rows: np.ndarray, k: int, guard: int) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """`k` contiguous held-out blocks over the used rows (sample indices `rows`, sorted), each
    holding about the same number of rows (a recording with rests has its rows in clusters), with
    a guard of `guard` samples at its seams left out of the training set (the filtered residual
    is correlated over about one filter length). Returns the segment starts (row positions) and,
    per block, (train, test) masks over the segments."""
    first = np.linspace(0, rows.size, k + 1).round().astype(int)  # row positions where blocks start
    cuts = []
    for a, b in itertools.pairwise(first):
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


@dataclass(frozen=True)
class Solution:
    """The fit of `solve`."""

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


def solve(
    Y: np.ndarray, tau: np.ndarray, Z: np.ndarray | None = None, rtol: float = 1e-7, hac_lags: int = 5
) -> Solution:
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
        a, b = g[lag * n :], g[: -lag * n]  # the same joint, `lag` rows apart
        meat += w * (a.T @ b + b.T @ a)
    return A_inv @ meat @ A_inv.T
