"""The one least-squares core of identification: τ ≈ X θ over rows and joints, by ordinary least
squares (IDIM-LS) or with instruments (IDIM-IV), on any set of contiguous row segments.

Everything `fit`, the parameter search and `diagnose` need comes from per-segment sufficient
statistics (`Stats`): XᵀX, Xᵀτ, τᵀτ (and ZᵀX, Zᵀτ with instruments Z) summed over each segment of
rows once. A fit on any union of segments is then a P×P solve, and its squared error on any
other union is a quadratic form: a grid search inside each held-out fold costs little more
than one fit. The products over rows are one matrix product per segment (the command line runs
BLAS on one thread: on a busy 2-core machine its threads spin-wait far longer than these take).

A grid search appends one effect's columns to a model's statistics, for every value of its
non-linear parameter (`Stats.extend` -> `Appended`): only the new blocks are summed, and a fit on
segment masks solves by the model's factorisation on each mask (computed once, kept) and the
k × k Schur complement of the k new columns, where every matrix is far enough above `RCOND` that
the minimum-norm solution is the plain one; elsewhere by the whole matrix's pseudo-inverse.

`solve` is the full fit on every row, with what a report needs: redundant columns named (those
the earlier ones explain: the regressor's rank deficiency), each parameter's standard deviation
from a heteroscedasticity- and autocorrelation-consistent (Newey–West) covariance, the residual.
`folds` cuts the rows into contiguous held-out blocks.
"""

from __future__ import annotations

import functools
import itertools
import threading
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import ClassVar, NamedTuple

import numpy as np

RCOND = 1e-10


def _flat(X: np.ndarray) -> np.ndarray:
    rows, n = X.shape[:2]
    return X.reshape(rows * n, -1) if X.ndim == 3 else X.reshape(rows * n)


def _products(A: np.ndarray, B: np.ndarray, starts: np.ndarray) -> np.ndarray:
    """Σ Aᵀ B over each segment's rows: A (..., rows, n, p), B (..., rows, n, q) -> (..., S, p, q),
    one matrix product per segment (no per-row outer products held)."""
    ends = np.r_[starts[1:], A.shape[-3]]
    la, lb = A.shape[:-3], B.shape[:-3]
    out = np.empty(np.broadcast_shapes(la, lb) + (starts.size, A.shape[-1], B.shape[-1]))
    for s, (a, b) in enumerate(zip(starts, ends, strict=True)):
        m = (b - a) * A.shape[-2]  # the segment's rows, stated: a block of no columns cannot infer them
        As = A[..., a:b, :, :].reshape(la + (m, A.shape[-1]))
        Bs = B[..., a:b, :, :].reshape(lb + (m, B.shape[-1]))
        out[..., s, :, :] = np.swapaxes(As, -1, -2) @ Bs
    return out


def _unit(E: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Columns (..., rows, n, k) scaled to unit RMS over their rows, and the scale (..., k)."""
    sE = np.sqrt(np.mean(E**2, axis=(-3, -2))) + 1e-300
    return E / sE[..., None, None, :], sE


@dataclass(frozen=True, eq=False)
class Stats:
    """Per-segment sums of τ ≈ X θ, the columns scaled to unit RMS (`scale`): G = XᵀX, g = Xᵀτ,
    yy = τᵀτ per segment (S, ...), and with instruments Z, H = ZᵀX and h = Zᵀτ (`iv`). Built from
    rows by `Stats.of`, which keeps the scaled rows (X, Z, tau) for `extend` (which returns
    `Appended`: these statistics with more columns, held in blocks)."""

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
    # per set of segment masks, the normal matrices summed over each mask and their factorisation (`_factor`)
    _factors: dict = field(init=False, repr=False, default_factory=dict)
    _whole: list = field(init=False, repr=False, default_factory=list)  # `whole_fit`

    @classmethod
    def of(cls, X: np.ndarray, tau: np.ndarray, starts: np.ndarray, Z: np.ndarray | None = None) -> Stats:
        """The statistics of X (rows, n, P), tau (rows, n) over the segments starting at `starts`;
        Z (rows, n, P) instruments or None (least squares)."""
        starts = np.asarray(starts, int)
        scale = np.sqrt(np.mean(X**2, axis=(0, 1))) + 1e-300
        X = X / scale
        Z = None if Z is None else Z / (np.sqrt(np.mean(Z**2, axis=(0, 1))) + 1e-300)
        t = tau[..., None]
        G = _products(X, X, starts)
        g = _products(X, t, starts)[..., 0]
        yy = _products(t, t, starts)[..., 0, 0]
        H = h = None
        if Z is not None:
            H = _products(Z, X, starts)
            h = _products(Z, t, starts)[..., 0]
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
    ) -> Appended:
        """These statistics with the columns E (rows, n, k) appended (instruments Ez), reusing
        the sums of the columns already here: what a grid search over an effect's non-linear
        parameter needs per grid point. E (V, rows, n, k): V sets of columns, each appended on
        its own (a grid's values at once; or a list of V arrays (rows, n, k)), stacked `budget`
        floats at a time: statistics with a leading axis V (`one(i)` is value i's). Without
        `Ez`, the result is least squares."""
        X, tau = self.X, self.tau
        assert X is not None and tau is not None, "appended statistics hold no rows: they are not extended again"
        if isinstance(E, (list, tuple)) or np.ndim(E) == 4:
            size = int(np.prod(np.shape(E[0])))
            step = int(max(1, budget // max(size, 1)))
            parts = [
                self._append(np.stack(list(E[i : i + step])), None if Ez is None else np.stack(list(Ez[i : i + step])))
                for i in range(0, len(E), step)
            ]
            return parts[0] if len(parts) == 1 else Appended.stacked(parts)
        return self._append(np.asarray(E), None if Ez is None else np.asarray(Ez))

    def _append(self, E: np.ndarray, Ez: np.ndarray | None) -> Appended:
        """`extend` of one set of columns E (rows, n, k) or a stack of them (V, rows, n, k)."""
        assert self.X is not None and self.tau is not None
        Es, sE = _unit(E)
        lead = E.shape[:-3]
        scale = np.concatenate([np.broadcast_to(self.scale, lead + self.scale.shape), sE], -1)
        t = self.tau[..., None]
        XE = _products(self.X, Es, self.starts)
        EE = _products(Es, Es, self.starts)
        gE = _products(Es, t, self.starts)[..., 0]
        iv = None
        if self.H is not None and Ez is not None:
            assert self.Z is not None, "statistics with instruments keep their rows' instruments"
            Zs = _unit(np.asarray(Ez))[0]
            # old instruments × new columns, new instruments × old columns, new × new, new instruments × τ
            iv = (
                _products(self.Z, Es, self.starts),
                _products(Zs, self.X, self.starts),
                _products(Zs, Es, self.starts),
                _products(Zs, t, self.starts)[..., 0],
            )
        return Appended(self, scale, XE, EE, gE, iv)

    def coef(self, use: np.ndarray) -> np.ndarray:
        """Scaled coefficients fitted on the segments `use` (bool mask): minimum-norm least
        squares, or the instrumental-variable solution when instruments were given."""
        A, b = self.normal()
        return np.linalg.lstsq(A[use].sum(0), b[use].sum(0), rcond=RCOND)[0]

    def coefs(self, masks: np.ndarray, lower: np.ndarray | None = None) -> np.ndarray:
        """`coef` on each of the segment masks (F, S) at once: (F, P), one batched pseudo-inverse
        (the same minimum-norm solution as `coef`'s, to rounding). `lower` (P,): a lower bound
        per parameter (−inf: none); a coefficient that falls below its bound is held there and
        the others fitted again, until none does (an active set that only grows: exact where the
        bounded columns are nearly orthogonal, as per-joint friction columns are)."""
        m = np.asarray(masks, float)
        o = self.over(m)
        b = m @ self.normal()[1]
        bounded = lower is not None and np.isfinite(lower).any()
        if o.factor is not None and not bounded:
            return np.einsum("fpq,fq->fp", o.factor.inv, b)
        low = None if lower is None else np.where(np.isfinite(lower), lower * self.scale, -np.inf)
        return _bounded(o.A, b, low, self.iv)

    def sses(self, C: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """Squared error of the coefficients C (F, P) on the segments of each mask (F, S), summed
        per mask: (F,)."""
        # (the sums over each mask's segments first: Σ_s m_s (yy_s − 2 cᵀg_s + cᵀG_s c) is one
        # quadratic form in the mask's G; clipped at 0 where rounding leaves an exact fit negative)
        m = np.asarray(masks, float)
        quad = np.einsum("...fp,...fpq,...fq->...f", C, self.over(m).G, C)
        return np.maximum(m @ self.yy - 2 * np.sum(C * (m @ self.g), -1) + quad, 0.0)

    def theta(self, c: np.ndarray) -> np.ndarray:
        """Scaled coefficients in the columns' own units."""
        return c / self.scale

    def over(self, m: np.ndarray) -> Over:
        """G and the normal matrix summed over each of the segment masks m (F, S), and the
        latter's factorisation (`Factor`), kept for the next call with the same masks (the
        statistics `retimed` share them: they depend on the columns only)."""
        key = (m.shape, m.tobytes())
        with _KEPT:
            if key not in self._factors:
                if len(self._factors) >= KEEP:
                    del self._factors[next(iter(self._factors))]
                Gm = _over_masks(m, self.G)
                Am = Gm if self.H is None else _over_masks(m, self.H)
                self._factors[key] = Over(Gm, Am, Factor.of(Am, self.iv))
            return self._factors[key]

    def whole_fit(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The normal matrix summed over every segment (P, P), the minimum-norm fit there (`RCOND`)
        and each segment's normal equations' residual b − A θ (S, P): kept (every set of columns
        appended to these statistics is scored against this fit)."""
        with _KEPT:
            if not self._whole:
                A, b = self.normal()
                Asum = A.sum(0)
                theta = np.linalg.lstsq(Asum, b.sum(0), rcond=RCOND)[0]
                self._whole.extend([Asum, theta, b - A @ theta])
            Asum, theta, u = self._whole
        return Asum, theta, u

    def retimed(self, tau: np.ndarray) -> Stats:
        """These statistics of the same columns with another torque (rows, n): a delay's value
        moves the torque only."""
        assert self.X is not None, "retimed statistics need their rows"
        t = tau[..., None]
        g = _products(self.X, t, self.starts)[..., 0]
        h = None if self.Z is None else _products(self.Z, t, self.starts)[..., 0]
        out = replace(self, g=g, yy=_products(t, t, self.starts)[..., 0, 0], h=h, tau=tau)
        object.__setattr__(out, "_factors", self._factors)
        return out


KEEP = 8  # sets of segment masks whose sums and factorisations a `Stats` keeps
_KEPT = threading.RLock()  # guards what a `Stats` keeps (candidates sharing one are judged on threads)


class Over(NamedTuple):
    """A `Stats`' sums over segment masks (F, S): G (F, P, P), the normal matrix A (G, or H with
    instruments) and A's factorisation (None where some A is not invertible well above `RCOND`)."""

    G: np.ndarray
    A: np.ndarray
    factor: Factor | None


KEPT_FITS = 4  # `Appended.coefs` kept per statistics (the last asked for)
SAFETY = 100.0  # the block solution is used where the whole matrix is this far above `RCOND` (else the pseudo-inverse)


@dataclass(frozen=True)
class Factor:
    """A batch of normal matrices A (F, P, P) summed over segment masks, inverted, with bounds on
    their singular values; built only where every A is well above `RCOND` (`SAFETY` times:
    there its pseudo-inverse is its inverse, whatever the rounding)."""

    inv: np.ndarray  # (F, P, P) A⁻¹
    low: np.ndarray  # (F,) A's smallest singular value
    high: np.ndarray  # (F,) A's largest

    @classmethod
    def of(cls, A: np.ndarray, iv: bool) -> Factor | None:
        """A's factorisation, or None where some A is not invertible well above `RCOND`."""
        if A.shape[-1] == 0:
            return None
        if iv:
            U, sv, Vt = np.linalg.svd(A)
            low, high = sv[..., -1], sv[..., 0]
            inv = np.einsum("...kp,...k,...qk->...pq", Vt, 1.0 / np.where(sv > 0, sv, 1.0), U)
        else:
            lam, V = np.linalg.eigh(A)
            low, high = lam[..., 0], np.abs(lam).max(axis=-1)
            inv = np.einsum("...pk,...k,...qk->...pq", V, 1.0 / np.where(lam > 0, lam, 1.0), V)
        if not np.all(low > SAFETY * RCOND * high):
            return None
        return cls(inv, low, high)


@dataclass(frozen=True, eq=False)
class Appended:
    """The statistics of `base` with k columns appended (`Stats.extend`), V sets of them at once
    (a leading axis V on every block; none for one set), held in blocks: the base's own sums, and
    per segment the products of the base's columns with the new ones (XE), of the new ones (EE)
    and of the new ones with τ (gE); with instruments, `iv` = (ZE, EX, EEz, hE): the base's
    instruments × the new columns, the new instruments × the base's columns, × the new columns,
    × τ. A fit on segment masks (`coefs`) solves by the base's factorisation on each mask and
    the k × k Schur complement of the new columns, where every matrix is well above `RCOND`
    (then the pseudo-inverse is the inverse, and both are the same solution); elsewhere by the
    whole matrix's pseudo-inverse, as `Stats.coefs`."""

    base: Stats
    scale: np.ndarray  # (..., P)
    XE: np.ndarray  # (..., S, P0, k)
    EE: np.ndarray  # (..., S, k, k)
    gE: np.ndarray  # (..., S, k)
    iv_blocks: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    _coefs: dict = field(init=False, repr=False, compare=False, default_factory=dict)  # `coefs` kept (masks, bounds)

    X: ClassVar[None] = None  # (no rows: not extended again)
    Z: ClassVar[None] = None
    tau: ClassVar[None] = None

    @property
    def starts(self) -> np.ndarray:
        """The segments' first rows."""
        return self.base.starts

    @property
    def yy(self) -> np.ndarray:
        """τᵀτ per segment (S,)."""
        return self.base.yy

    @property
    def iv(self) -> bool:
        """Instrumental variables (else least squares)."""
        return self.iv_blocks is not None

    @functools.cached_property
    def G(self) -> np.ndarray:
        """XᵀX per segment, whole: (..., S, P, P)."""
        return _blocks(self.base.G, self.XE, np.swapaxes(self.XE, -1, -2), self.EE)

    @functools.cached_property
    def g(self) -> np.ndarray:
        """Xᵀτ per segment, whole: (..., S, P)."""
        return np.concatenate([np.broadcast_to(self.base.g, self.gE.shape[:-1] + self.base.g.shape[-1:]), self.gE], -1)

    @functools.cached_property
    def H(self) -> np.ndarray | None:
        """ZᵀX per segment, whole (None: least squares)."""
        if self.iv_blocks is None or self.base.H is None:
            return None
        ZE, EX, EEz, _ = self.iv_blocks
        return _blocks(self.base.H, ZE, EX, EEz)

    @functools.cached_property
    def h(self) -> np.ndarray | None:
        """Zᵀτ per segment, whole (None: least squares)."""
        if self.iv_blocks is None or self.base.h is None:
            return None
        hE = self.iv_blocks[3]
        return np.concatenate([np.broadcast_to(self.base.h, hE.shape[:-1] + self.base.h.shape[-1:]), hE], -1)

    def normal(self) -> tuple[np.ndarray, np.ndarray]:
        """The per-segment normal equations (A, b), whole: (H, h) with instruments, else (G, g)."""
        if self.H is not None and self.h is not None:
            return self.H, self.h
        return self.G, self.g

    def tests_appended(self, test: np.ndarray) -> bool:
        """Whether the column mask `test` (P,) holds exactly the appended columns (one set: no
        leading axis)."""
        k = self.EE.shape[-1]
        return self.EE.ndim == 3 and test.size == self.scale.shape[-1] and bool(test[-k:].all() and not test[:-k].any())

    def normal_blocks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The appended part of the per-segment normal equations [[A, B], [C, D]] c = [b, bE]:
        B (..., S, P0, k), C (..., S, k, P0), D (..., S, k, k), bE (..., S, k)."""
        if self.iv_blocks is None:
            return self.XE, np.swapaxes(self.XE, -1, -2), self.EE, self.gE
        return self.iv_blocks

    @staticmethod
    def stacked(parts: list[Appended]) -> Appended:
        """Batches of `Stats.extend` (leading axis V) joined into one."""
        ivs = [p.iv_blocks for p in parts]
        iv = None if ivs[0] is None else tuple(np.concatenate([b[j] for b in ivs if b is not None]) for j in range(4))
        return Appended(
            parts[0].base,
            np.concatenate([p.scale for p in parts]),
            np.concatenate([p.XE for p in parts]),
            np.concatenate([p.EE for p in parts]),
            np.concatenate([p.gE for p in parts]),
            iv,  # type: ignore[arg-type]
        )

    def one(self, i: int) -> Appended:
        """Value i's statistics of a batch (V sets of columns)."""
        return Appended(
            self.base,
            self.scale[i],
            self.XE[i],
            self.EE[i],
            self.gE[i],
            None if self.iv_blocks is None else tuple(b[i] for b in self.iv_blocks),  # type: ignore[arg-type]
        )

    def theta(self, c: np.ndarray) -> np.ndarray:
        """Scaled coefficients in the columns' own units."""
        return c / self.scale

    def _over(self, m: np.ndarray) -> tuple:
        """The appended blocks summed over the masks m (F, S): the normal equations' B, C, D, bE
        ([[A, B], [C, D]] c = [b, bE]) and G's (GB, GD) and g's (gE) for the errors."""

        def over(x: np.ndarray, lead: int) -> np.ndarray:  # (..., S, *trailing `lead` axes) -> (..., F, ...)
            return np.moveaxis(np.tensordot(m, x, axes=([1], [-1 - lead])), 0, -1 - lead)

        GB, GD, gE = over(self.XE, 2), over(self.EE, 2), over(self.gE, 1)
        if self.iv_blocks is None:
            return GB, np.swapaxes(GB, -1, -2), GD, gE, GB, GD, gE
        ZE, EX, EEz, hE = self.iv_blocks
        return over(ZE, 2), over(EX, 2), over(EEz, 2), over(hE, 1), GB, GD, gE

    def coefs(self, masks: np.ndarray, lower: np.ndarray | None = None) -> np.ndarray:
        """`Stats.coefs` of the whole statistics: (..., F, P). The last few asked for are kept
        (a search asks the fit on every segment for its choice and again for its bounds)."""
        m = np.asarray(masks, float)
        key = (m.shape, m.tobytes(), None if lower is None else np.asarray(lower, float).tobytes())
        kept = self._coefs.get(key)
        if kept is None:
            kept = self._coefs[key] = self._solved(m, lower)
            while len(self._coefs) > KEPT_FITS:
                self._coefs.pop(next(iter(self._coefs)))
        return kept.copy()

    def _solved(self, m: np.ndarray, lower: np.ndarray | None) -> np.ndarray:
        P0 = self.base.G.shape[-1]
        o = self.base.over(m)
        B, C, D, bE, *_ = self._over(m)
        k = D.shape[-1]
        b0 = m @ self.base.normal()[1]  # (F, P0)
        F = m.shape[0]
        low = np.full(self.scale.shape[:-1] + (F, P0 + k), -np.inf)
        if lower is not None:
            low = np.broadcast_to(np.where(np.isfinite(lower), lower * self.scale, -np.inf)[..., None, :], low.shape)
        fac = o.factor
        if fac is None or k == 0 or np.isfinite(low[..., :P0]).any():  # the whole matrix's pseudo-inverse
            M = _blocks(o.A, B, C, D)
            r = np.concatenate([np.broadcast_to(b0, bE.shape[:-1] + b0.shape[-1:]), bE], -1)
            return _bounded(M, r, low, self.iv)
        lowE = low[..., P0:]
        W = fac.inv @ B  # (..., F, P0, k) A⁻¹ B
        S = D - C @ W  # the Schur complement of A
        CA = np.swapaxes(W, -1, -2) if not self.iv else C @ fac.inv  # C A⁻¹
        y0 = np.einsum("fpq,fq->fp", fac.inv, b0)
        # the whole matrix's singular values: the largest at most its norm (PSD: ‖A‖ + tr D); the smallest
        # at least min(σ(A), σ(S)) / (‖L⁻¹‖ ‖R⁻¹‖), M = L diag(A, S) R with L⁻¹ = [[I, 0], [−C A⁻¹, I]],
        # R⁻¹ = [[I, −A⁻¹ B], [0, I]]
        if self.iv:
            size = np.sqrt(np.sum(o.A**2, axis=(-2, -1)) + sum(np.sum(x * x, axis=(-2, -1)) for x in (B, C, D)))
        else:
            size = fac.high + np.trace(D, axis1=-2, axis2=-1)
        stretch = (1 + np.sqrt(np.sum(W * W, axis=(-2, -1)))) * (1 + np.sqrt(np.sum(CA * CA, axis=(-2, -1))))
        fill = (fac.high + np.sqrt(np.sum(D * D, axis=(-2, -1))))[..., None]  # a held column's decoupled 1 × 1 block

        def solve(held: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            """The coefficients with the appended columns `held` at their bound, and where the block
            solution stands for the pseudo-inverse's (`good`)."""
            xE = np.where(held, lowE, 0.0)
            y = y0 - np.einsum("...pk,...k->...p", W, xE)  # A⁻¹ (b − B x)
            rhs = bE - np.einsum("...kj,...j->...k", D, xE) - np.einsum("...kp,...p->...k", C, y)
            both = held[..., :, None] | held[..., None, :]
            Sh = np.where(both, 0.0, S) + np.where(held, fill, 0.0)[..., None] * np.eye(k)
            small = np.minimum(fac.low, np.linalg.svd(Sh, compute_uv=False)[..., -1])
            good = small / stretch > SAFETY * RCOND * size
            d = np.linalg.solve(np.where(good[..., None, None], Sh, np.eye(k)), np.where(held, 0.0, rhs)[..., None])
            d = np.where(held, 0.0, d[..., 0])
            return np.concatenate([y - np.einsum("...pk,...k->...p", W, d), np.where(held, lowE, d)], -1), good

        held = np.zeros(lowE.shape, bool)
        out, good = solve(held)
        for _ in range(k):
            more = (lowE > out[..., P0:]) & ~held
            if not more.any():
                break
            held |= more
            out, now = solve(held)
            good &= now
        if not good.all():  # the whole matrix's pseudo-inverse where the blocks are not far enough from singular
            bad = np.nonzero(~good)
            f = bad[-1]
            M = _blocks(o.A[f], B[bad], C[bad], D[bad])
            r = np.concatenate([b0[f], bE[bad]], -1)
            out[bad] = _bounded(M, r, low[bad], self.iv)
        return out

    def sses(self, C: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """`Stats.sses` of the whole statistics: (..., F)."""
        m = np.asarray(masks, float)
        P0 = self.base.G.shape[-1]
        G0 = self.base.over(m)[0]
        *_, GB, GD, gE = self._over(m)
        c0, cE = C[..., :P0], C[..., P0:]
        quad = (
            np.einsum("...fp,fpq,...fq->...f", c0, G0, c0)
            + 2 * np.einsum("...fp,...fpq,...fq->...f", c0, GB, cE)
            + np.einsum("...fp,...fpq,...fq->...f", cE, GD, cE)
        )
        lin = np.sum(c0 * (m @ self.base.g), -1) + np.sum(cE * gE, -1)
        return np.maximum(m @ self.yy - 2 * lin + quad, 0.0)


def _bounded(M: np.ndarray, r: np.ndarray, low: np.ndarray | None, iv: bool) -> np.ndarray:
    """Minimum-norm solutions of M c = r (..., P, P), (..., P), each coefficient held at its lower
    bound `low` (in the scaled units of c, broadcast to c's shape; −inf: none) where it would fall
    below it (see `Stats.coefs`)."""
    C, inverse = _solve(M, r, iv)
    if low is None or not np.isfinite(low).any():
        return C
    low, r = np.broadcast_to(low, C.shape), np.broadcast_to(r, C.shape)
    M = np.broadcast_to(M, C.shape[:-1] + M.shape[-2:])
    # (least squares: a symmetric M whose eigenvalues are all kept keeps them on any coordinates it is
    # restricted to: its principal submatrices' eigenvalues lie between its smallest and largest)
    kept = inverse if not iv else np.zeros(inverse.shape, bool)
    held = np.zeros(C.shape, bool)
    for _ in range(C.shape[-1]):
        more = (low > C) & ~held
        again = more.any(-1)  # the solutions that hold one more coefficient (the others stay as they are)
        if not again.any():
            break
        held |= more
        h, m = held[again], M[again]
        x = np.where(h, low[again], 0.0)
        free = (~h).astype(float)
        r2 = (r[again] - np.einsum("...pq,...q->...p", m, x)) * free
        known = kept[again]
        c = np.empty(r2.shape)
        if known.any():
            c[known] = _inverse_solve(m[known], r2[known], h[known])
        if not known.all():
            f = free[~known]
            c[~known] = _solve(m[~known] * f[..., :, None] * f[..., None, :], r2[~known], iv, h[~known])[0]
        C[again] = np.where(h, low[again], c)
    return C


def _solve(M: np.ndarray, r: np.ndarray, iv: bool, held: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-norm solutions of M c = r for a batch (..., P, P), (..., P): the pseudo-inverse's,
    its singular values (least squares, M symmetric: eigenvalues) at most `RCOND` times the
    largest left out. `held` (..., P): coordinates whose rows and columns of M and entries of r
    are 0 (their solution is 0). Where nothing but them is left out the pseudo-inverse is the
    inverse on the other coordinates and the solution an LU solve's (a fraction of a
    decomposition's cost); elsewhere the decomposition's. Returns the solutions and where the
    inverse gave them."""
    P = M.shape[-1]
    # (on M's own batch, which r may broadcast over; least squares: eigenvalues, cheaper than singular values)
    s = np.linalg.svd(M, compute_uv=False) if iv else np.linalg.eigvalsh(M)
    kept = np.sum(s > RCOND * np.abs(s).max(axis=-1, keepdims=True), axis=-1)
    lead = np.broadcast_shapes(M.shape[:-2], r.shape[:-1])
    inverse = np.broadcast_to(kept == (P if held is None else P - np.sum(held, axis=-1)), lead)
    if inverse.all():
        return _inverse_solve(M, r, held), inverse
    M, r = np.broadcast_to(M, lead + (P, P)), np.broadcast_to(r, lead + (P,))
    out = np.empty(lead + (P,))
    if inverse.any():
        out[inverse] = _inverse_solve(M[inverse], r[inverse], None if held is None else held[inverse])
    out[~inverse] = _pinv_solve(M[~inverse], r[~inverse], iv)
    return out, inverse


def _inverse_solve(M: np.ndarray, r: np.ndarray, held: np.ndarray | None) -> np.ndarray:
    """`_solve` where M is invertible on the coordinates not `held`: (..., P, P), (..., P),
    broadcast; an LU solve with the held coordinates' rows and columns those of the identity
    (their r is 0, and so their solution)."""
    if held is not None:
        free = ~held
        M = np.where(free[..., :, None] & free[..., None, :], M, np.eye(M.shape[-1]))
    return np.linalg.solve(M, r[..., None])[..., 0]


def _pinv_solve(M: np.ndarray, r: np.ndarray, iv: bool) -> np.ndarray:
    """`_solve` by the decomposition: (n, P, P), (n, P)."""
    if iv:
        return np.einsum("...pq,...q->...p", np.linalg.pinv(M, rcond=RCOND), r)
    # least squares: M is symmetric, its pseudo-inverse from its eigenvectors (cheaper than an SVD)
    lam, U = np.linalg.eigh(M)
    keep = lam > RCOND * np.abs(lam).max(axis=-1, keepdims=True)
    inv = np.where(keep, 1.0 / np.where(keep, lam, 1.0), 0.0)
    return np.einsum("...pk,...k->...p", U, inv * np.einsum("...pk,...p->...k", U, r))


def _over_masks(m: np.ndarray, A: np.ndarray) -> np.ndarray:
    """Σ_s m_fs A_s for masks m (F, S) and per-segment matrices A (..., S, P, Q): (..., F, P, Q)."""
    P, Q = A.shape[-2:]
    return (m @ A.reshape(A.shape[:-3] + (A.shape[-3], P * Q))).reshape(A.shape[:-3] + (m.shape[0], P, Q))


def _blocks(A: np.ndarray, B: np.ndarray, C: np.ndarray, D: np.ndarray) -> np.ndarray:
    """[[A, B], [C, D]] along the last two axes, A broadcast over the others' leading axes."""
    A = np.broadcast_to(A, B.shape[:-1] + A.shape[-1:])
    return np.concatenate([np.concatenate([A, B], -1), np.concatenate([C, D], -1)], -2)


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
