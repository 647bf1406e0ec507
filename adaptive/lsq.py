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

The same statistics test whether columns are missing from a model (`block_scores`, `score_p`:
their score per block, Wald's statistic with the blocks as clusters, its null distribution by
sign flips of the blocks), and `correlation_time` says how long a residual stays correlated.
"""

from __future__ import annotations

import functools
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

    def _sum(self, per_row: np.ndarray, axis: int = 0) -> np.ndarray:
        return np.add.reduceat(per_row, self.starts, axis=axis)

    def target(self, tau: np.ndarray) -> "Stats":
        """Another torque for the same columns (a delay searched: the torque moves, X stays)."""
        self.tau = tau
        self.g = self._sum(np.einsum("rnp,rn->rp", self.X, tau))
        self.yy = self._sum(np.einsum("rn,rn->r", tau, tau))
        if self.iv:
            self.H = self._sum(np.einsum("rnp,rnq->rpq", self.Z, self.X))
            self.h = self._sum(np.einsum("rnp,rn->rp", self.Z, tau))
        return self

    def extend(self, E: np.ndarray, Ez: np.ndarray | None = None, budget: float = 8e6) -> "Stats":
        """These statistics with the columns E (rows, n, k) appended (instruments Ez), reusing
        the sums of the columns already here: what a grid search over an effect's non-linear
        parameter needs per grid point. E (V, rows, n, k): V sets of columns, each appended on
        its own (a grid's values at once; or a list of V arrays (rows, n, k), stacked a chunk at a
        time): statistics with a leading axis V (`one(i)` is value i's), worked out `budget`
        floats of products at a time."""
        if isinstance(E, (list, tuple)) or (np.ndim(E) == 4):
            rows, k = np.shape(E[0])[0], np.shape(E[0])[-1]
            step = int(max(1, budget // max(rows * (self.X.shape[2] + k) * k, 1)))
            if isinstance(E, (list, tuple)) or len(E) > step:
                parts = [self.extend(np.stack(E[i:i + step]), None if Ez is None else np.stack(Ez[i:i + step]), budget)
                         for i in range(0, len(E), step)]
                return parts[0] if len(parts) == 1 else _stacked(parts)
        E = np.asarray(E)
        ax = E.ndim - 3  # the rows' axis
        new = object.__new__(Stats)
        new.starts = self.starts
        sE = np.sqrt(np.mean(E**2, axis=(-3, -2))) + 1e-300
        Es = E / sE[..., None, None, :]
        lead = E.shape[:ax]
        new.scale = np.concatenate([np.broadcast_to(self.scale, lead + self.scale.shape), sE], -1)
        XE = self._sum(np.einsum("rnp,...rnq->...rpq", self.X, Es), ax)
        EE = self._sum(np.einsum("...rnp,...rnq->...rpq", Es, Es), ax)
        new.G = _blocks(self.G, XE, np.swapaxes(XE, -1, -2), EE)
        new.g = np.concatenate([np.broadcast_to(self.g, lead + self.g.shape),
                                self._sum(np.einsum("...rnp,rn->...rp", Es, self.tau), ax)], -1)
        # (the rows themselves are not kept: an extended Stats is a grid point, not extended again)
        new.yy, new.tau, new.X, new.Z, new.iv = self.yy, self.tau, None, None, False
        if self.iv and Ez is not None:
            Ez = np.asarray(Ez)
            Zs = Ez / (np.sqrt(np.mean(Ez**2, axis=(-3, -2))) + 1e-300)[..., None, None, :]
            ZE = self._sum(np.einsum("rnp,...rnq->...rpq", self.Z, Es), ax)  # old instruments × new columns
            EX = self._sum(np.einsum("...rnp,rnq->...rpq", Zs, self.X), ax)  # new instruments × old columns
            EEz = self._sum(np.einsum("...rnp,...rnq->...rpq", Zs, Es), ax)
            new.H = _blocks(self.H, ZE, EX, EEz)
            new.h = np.concatenate([np.broadcast_to(self.h, lead + self.h.shape),
                                    self._sum(np.einsum("...rnp,rn->...rp", Zs, self.tau), ax)], -1)
            new.iv = True
        return new

    def one(self, i: int) -> "Stats":
        """Value i's statistics of an `extend`ed batch (V sets of columns)."""
        new = object.__new__(Stats)
        new.__dict__.update(self.__dict__)
        for k in ("G", "g", "scale") + (("H", "h") if self.iv else ()):
            setattr(new, k, getattr(self, k)[i])
        return new

    def coef(self, use: np.ndarray) -> np.ndarray:
        """Scaled coefficients fitted on the segments `use` (bool mask): minimum-norm least
        squares, or the instrumental-variable solution when instruments were given."""
        if not self.iv:
            A, b = self.G[use].sum(0), self.g[use].sum(0)
        else:
            A, b = self.H[use].sum(0), self.h[use].sum(0)
        return np.linalg.lstsq(A, b, rcond=RCOND)[0]

    def coefs(self, masks: np.ndarray, lower: np.ndarray | None = None) -> np.ndarray:
        """`coef` on each of the segment masks (F, S) at once: (F, P), one batched pseudo-inverse
        (the same minimum-norm solution as `coef`'s, to rounding); (V, F, P) for a batch of V
        values (`extend`). `lower` (P,): a lower bound per parameter (−inf: none); a coefficient
        that falls below its bound is held there and the others fitted again, until none does
        (an active set that only grows: exact where the bounded columns are nearly orthogonal,
        as per-joint friction columns are)."""
        A, b = (self.H, self.h) if self.iv else (self.G, self.g)
        m = np.asarray(masks, float)
        M, r = _over_masks(m, A), m @ b
        C = self._solve(M, r)
        if lower is None or not np.isfinite(lower).any():
            return C
        low = np.where(np.isfinite(lower), lower * self.scale, -np.inf)[..., None, :]  # in the scaled units of C
        held = np.zeros(C.shape, bool)
        for _ in range(C.shape[-1]):
            more = (C < low) & ~held
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
        per mask: (F,), as `sse(...).sum()` row by row; (V, F) for a batch (C (V, F, P))."""
        # (the sums over each mask's segments first: Σ_s m_s (yy_s − 2 cᵀg_s + cᵀG_s c) is one
        # quadratic form in the mask's G; clipped at 0 where rounding leaves an exact fit negative)
        m = np.asarray(masks, float)
        Gm = _over_masks(m, self.G)
        quad = np.einsum("...fp,...fpq,...fq->...f", C, Gm, C)
        return np.maximum(m @ self.yy - 2 * np.sum(C * (m @ self.g), -1) + quad, 0.0)

    def sse(self, c: np.ndarray, use: np.ndarray) -> np.ndarray:
        """Squared error of scaled coefficients `c` on each segment of `use`."""
        # (a quadratic form: clipped at 0 where rounding leaves an exact fit slightly negative)
        return np.maximum(self.yy[use] - 2 * self.g[use] @ c + np.einsum("p,spq,q->s", c, self.G[use], c), 0.0)

    def theta(self, c: np.ndarray) -> np.ndarray:
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
    new = object.__new__(Stats)
    new.__dict__.update(parts[0].__dict__)
    for k in ("G", "g", "scale") + (("H", "h") if parts[0].iv else ()):
        setattr(new, k, np.concatenate([getattr(p, k) for p in parts]))
    return new


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


def block_scores(st: Stats, test: np.ndarray, blocks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The score of the columns `test` (a bool mask over the columns of `st`: a candidate's, on
    top of a model of the others) per block, (G, k), and each block's share of their
    information, (G, k, k).

    The model of the other columns is fitted on every row (least squares, or IV when `st` has
    instruments); each tested column's score is its (instrument's) product with that residual,
    summed over a block, with the part the model's parameters would absorb taken out
    (partialled: the instrument Z̃ = Z_E − Z_X C, C = H_XX⁻¹ᵀ H_EXᵀ with H = ZᵀX over every row,
    so that Z̃ᵀX = 0; Z = X for least squares). Their sum is what the tested columns would
    explain; a block's information Q_b = (Z̃ᵀE)_b is its share of the signal they carry: fitted,
    they take Q_b β̂ out of block b's score. `blocks` (G, S): the segments each block holds."""
    A, b = (st.H, st.h) if st.iv else (st.G, st.g)
    test = np.asarray(test, bool)
    idx = np.r_[np.flatnonzero(~test), np.flatnonzero(test)]
    A, b = A[:, idx][:, :, idx], b[:, idx]
    p = int((~test).sum())
    Asum = A.sum(0)
    theta = np.linalg.lstsq(Asum[:p, :p], b[:, :p].sum(0), rcond=RCOND)[0] if p else np.zeros(0)
    u = b - A[:, :, :p] @ theta  # (S, P): each instrument against the model's residual, per segment
    T = np.eye(len(idx))[:, p:]  # the instruments Z̃ as combinations of Z's columns: (P, k)
    if p:
        T[:p] = -np.linalg.lstsq(Asum[:p, :p].T, Asum[p:, :p].T, rcond=RCOND)[0]
    masks = np.asarray(blocks, float)
    k = T.shape[1]
    TA = (T.T[None] @ A[:, :, p:]).reshape(A.shape[0], k * k)  # (S, k·k): each segment's Z̃ᵀE
    return Scores((masks @ (u @ T), (masks @ TA).reshape(masks.shape[0], k, k)))


class Scores(tuple):
    """(s, Q) of `block_scores`; its `_jackknifed` reduction worked out once (`score_p` and
    `detectable` both judge it)."""

    def reduced(self):
        if "_reduced" not in self.__dict__:
            self._reduced = _jackknifed(*self)
        return self._reduced


def _reduced(x) -> tuple | None:
    return x.reduced() if isinstance(x, Scores) else _jackknifed(*x)


FLIPS = 2000  # sign-flip draws of `score_p` at least (its smallest p: 1/(draws + 1)) ...
FLIPS_PER_ALPHA = 4  # ... and at least this many over the level a p is judged at
FLIP_CHUNK = 250  # draws at a time, at most ...
FLIP_MEMORY = 4_000_000  # ... and at most this many floats of a chunk's T·w (a 7-joint chain's 14 cogging columns)
MIN_EFFECTIVE_BLOCKS = 12.0  # below this many blocks sharing the information, the exact flips (see score_p)


def _jackknifed(s: np.ndarray, Q: np.ndarray):
    """One value's block scores s (G, k) and information Q (G, k, k) reduced to the directions the
    columns identify (R: Q's eigenvectors above rounding): (k, their eigenvalues, s R, RᵀQR,
    (Σ RᵀQR)⁻¹, L, the jackknifed noise scores d); None when nothing is identifiable or the
    blocks are too few. Each block's noise score is taken as if the candidate were fitted without
    it (the cluster jackknife, CR3): a block that holds much of the columns' information pulls
    the fit toward itself, and its own residual score would understate its noise."""
    Qs = Q.sum(0)
    lam, U = np.linalg.eigh(0.5 * (Qs + Qs.T))
    keep = lam > 1e-10 * max(lam.max(initial=0.0), 1e-300)
    k = int(keep.sum())
    if k == 0 or s.shape[0] <= 2 * k:
        return None
    R = U[:, keep]
    sr, Qr = s @ R, np.einsum("ki,gkl,lj->gij", R, Q, R)
    Qi = np.linalg.pinv(Qr.sum(0))
    L = np.linalg.pinv(np.eye(k)[None] - Qr @ Qi)
    dj = (L @ (sr - Qr @ (Qi @ sr.sum(0)))[..., None])[..., 0]
    return k, lam[keep], sr, Qr, Qi, L, dj, R


def score_p(scores: list[tuple[np.ndarray, np.ndarray]], alpha: float = 0.05, seed: int = 0,
            stop_above: float = 0.1, signed: np.ndarray | None = None) -> tuple[float, int, str]:
    """p of 'the candidate's columns are missing from the model', from their block scores (one
    `block_scores` per value of the candidate's searched parameter; one: nothing searched).

    Per value, Wald's statistic with the blocks as clusters: W = (Σ s)ᵀ Ω⁻¹ (Σ s), Ω = Σ d dᵀ the
    spread of the blocks' scores once the candidate is fitted without each (d_b = L_b (s_b −
    Q_b β̂), β̂ = Q⁻¹ Σ s, L_b = (I − Q_b Q⁻¹)⁻¹: the cluster jackknife; noise only, a missing
    effect's own signal, large in some blocks and small in others, does not count as noise);
    over a search, its largest over the values. Its null distribution comes from random sign
    flips of whole blocks, the statistic computed again from the flipped scores exactly as from
    the data (β̂, the jackknife and Ω included). What is flipped depends on how many blocks
    share the columns' information (the effective number k² / Σ_b tr(Q_b Q⁻¹)², over the values
    searched, the smallest): at least `MIN_EFFECTIVE_BLOCKS`, the blocks' noise scores d (the
    wild cluster bootstrap, Cameron, Gelbach & Miller 2008: the null's spread whatever the
    signal); fewer, the scores s themselves (an exact randomization test where the blocks are
    independent and their scores symmetric under the null: with the information in a few
    blocks, their noise cannot be told from their signal, and the wild bootstrap's p would be
    too small; measured in tests/adaptive/test_score_test.py). The same flips serve every value
    searched: the search is redone in each draw, so what it buys is paid for. p = (1 + draws at
    least as large)/(1 + draws), with enough draws that a p below `alpha` (the level it is
    judged at) can show (`FLIPS`, at least `FLIPS_PER_ALPHA`/alpha); they stop early once p is
    surely above `stop_above`.

    `signed` (a bool per tested column): the columns whose coefficient physics keeps at or above
    0 (a friction level, a spring's stiffness). The alternative is then one-sided in them, and
    the statistic counts only what the physical sign explains: Wald's minus the squared distance
    from β̂ to the coefficients the physics allows, in β̂'s precision metric (`_physical`: the
    one-sided likelihood-ratio form), equal to Wald's where β̂ has the physical sign, smaller
    where it has not, 0 where only the wrong sign is seen. The flips compute the same statistic,
    so its level holds as Wald's does; its power is a one-sided test's (about a two-sided one at
    twice the level, for one column). Returns (p, the index of the value with the largest W,
    "wild" or "exact")."""
    draws = max(FLIPS, int(np.ceil(FLIPS_PER_ALPHA / alpha)))
    prepared, effective = [], np.inf
    observed = np.full(len(scores), -np.inf)
    signed = None if signed is None or not np.any(signed) else np.asarray(signed, bool)
    for v, x in enumerate(scores):
        reduced = _reduced(x)
        if reduced is None:
            continue
        k, _, sr, Qr, Qi, L, dj, R = reduced
        omega = dj.T @ dj
        m = _physical(sr.sum(0)[None, None], Qr.sum(0)[None], Qi[None], R[None], omega[None, None], signed)[0, 0]
        observed[v] = m @ _solve_psd(omega[None], m[None])[0]
        lev = np.einsum("gij,ji->g", Qr, Qi)  # each block's share of the information (Σ = k)
        effective = min(effective, k * k / max(float(np.sum(lev**2)), 1e-300))
        prepared.append((k, sr, dj, Qr, Qi, L, R))
    if not prepared:
        return 1.0, 0, "none"
    # the blocks' noise scores flipped where many blocks share the information (the wild
    # bootstrap's power); the scores themselves where a few hold most of it (an exact
    # randomization test: the noise of those few cannot be told from their signal)
    wild = effective >= MIN_EFFECTIVE_BLOCKS
    by_k: dict[int, list] = {}  # the values, grouped by how many identifiable directions they have
    for k, sr, dj, Qr, Qi, L, R in prepared:
        by_k.setdefault(k, []).append((dj if wild else sr, Qr, Qi, L, R))
    G = scores[0][0].shape[0]
    # A draw's pseudo-scores are w_b d_b (d: the jackknifed noise scores, or the scores s
    # themselves for the exact flips, signs flipped); its statistic is computed from them as from
    # the data: m = Σ w d, β = Q⁻¹ m, the blocks'
    # jackknifed scores L_b (w_b d_b − Q_b β) = w_b d2_b − Q2_b β (d2 = L d, Q2 = L Q), and per k,
    # the values stacked, their Ω = D − T·β − (T·β)ᵀ + S·β·β with D = Σ d2 d2ᵀ (signs squared
    # away), T = Σ w_b d2_b ⊗ Q2_b (one matrix product over the blocks), S = Σ Q2_b ⊗ Q2_b
    pre = []
    for k, vals in by_k.items():
        d = np.stack([x[0] for x in vals])  # (V, G, k)
        Qi = np.stack([x[2] for x in vals])
        L = np.stack([x[3] for x in vals])
        d2 = (L @ d[..., None])[..., 0]
        Q2 = L @ np.stack([x[1] for x in vals])  # (V, G, k, k)
        D = np.einsum("vgi,vgj->vij", d2, d2)
        T = np.einsum("vgi,vgjl->gvijl", d2, Q2).reshape(G, -1)
        S = np.einsum("vgil,vgjm->vlmij", Q2, Q2).reshape(len(vals), k * k, k * k)
        Qs, R = np.stack([x[1].sum(0) for x in vals]), np.stack([x[4] for x in vals])
        pre.append((k, len(vals), d.transpose(1, 0, 2).reshape(G, -1), Qi, D, T, S, Qs, R))
    best = int(np.argmax(observed))
    rng = np.random.default_rng(seed)
    exceed = done = 0
    per_draw = sum(V * k**3 for k, V, *_ in pre)  # floats a draw's T·w takes
    chunk = int(np.clip(FLIP_MEMORY // max(per_draw, 1), 1, FLIP_CHUNK))
    while done < draws:
        n = min(chunk, draws - done)
        w = rng.choice((-1.0, 1.0), size=(n, G))
        top = np.full(n, -np.inf)
        for k, V, dflat, Qi, D, T, S, Qs, R in pre:
            m = (w @ dflat).reshape(n, V, k)
            beta = (Qi[None] @ m[..., None])[..., 0]  # (n, V, k)
            tb = ((w @ T).reshape(n, V, k * k, k) @ beta[..., None]).reshape(n, V, k, k)
            bb = (beta[..., :, None] * beta[..., None, :]).reshape(n, V, 1, k * k)
            omega = D[None] - tb - tb.transpose(0, 1, 3, 2) + (bb @ S[None]).reshape(n, V, k, k)
            m = _physical(m, Qs, Qi, R, omega, signed)
            W = np.sum(m * _solve_psd(omega.reshape(-1, k, k), m.reshape(-1, k)).reshape(n, V, k), axis=2)
            top = np.maximum(top, W.max(1))
        exceed += int(np.sum(top >= observed[best] * (1 - 1e-9)))
        done += n
        if (1 + exceed) / (1 + draws) > stop_above:  # surely above it, whatever the rest would give
            break
    return (1 + exceed) / (1 + done), best, "wild" if wild else "exact"


def _physical(m: np.ndarray, Qs: np.ndarray, Qi: np.ndarray, R: np.ndarray, omega: np.ndarray,
              signed: np.ndarray | None) -> np.ndarray:
    """The summed scores m (n, V, k), in the identified directions R (V, K, k) of each value's K
    tested columns (Qs = Σ_b Q_b there, Qi its inverse, omega (n, V, k, k) the scores' spread),
    reduced to what the physical sign explains (`score_p`): β̂ = Qi m projected on the
    coefficients the physics allows, the `signed` columns' Rβ ≥ 0, in the metric of β̂'s own
    precision A = Qs Ω⁻¹ Qs (the one-sided likelihood-ratio statistic: Wald's minus the
    distance to that cone); returned as Qs β⁺, whose Ω⁻¹-norm is that statistic. The projection
    holds the columns of the wrong sign at 0 and refits the rest, then any that cross in turn (an
    active set that only grows: exact for one signed column, and whatever it gives the flips
    give too). Unchanged where nothing is signed."""
    if signed is None:
        return m
    K = R.shape[1]
    b = np.einsum("vij,nvj->nvi", Qi, m)
    Ainv = Qi[None] @ omega @ Qi[None]  # (n, V, k, k): β̂'s covariance
    S = np.einsum("vKk,nvkl,vJl->nvKJ", R, Ainv, R)  # the columns' coefficients' covariance
    beta, Cb = b, np.einsum("vKk,nvk->nvK", R, b)
    held = signed & (Cb < 0)
    for _ in range(int(np.sum(signed))):
        if not held.any():
            break
        h = held.astype(float)
        ridge = 1e-12 * np.trace(S, axis1=-2, axis2=-1)[..., None, None] + 1e-300
        Sm = S * h[..., :, None] * h[..., None, :] + (np.eye(K) * (1 - h)[..., None, :]) + ridge * np.eye(K)
        lam = np.linalg.solve(Sm, (Cb * h)[..., None])[..., 0]  # the held columns' multipliers
        beta = b - (Ainv @ np.einsum("vKk,nvK->nvk", R, lam)[..., None])[..., 0]
        Cb_now = np.einsum("vKk,nvk->nvK", R, beta)
        beta = beta - np.einsum("vKk,nvK->nvk", R, Cb_now * h)  # (the held ones exactly at 0, not to rounding)
        more = signed & ~held & (Cb_now < 0)
        if not more.any():
            break
        held = held | more
    return np.einsum("vij,nvj->nvi", Qs, beta)


POWER = 0.8  # a detection limit is the size found this often


def detectable(scores: list[tuple[np.ndarray, np.ndarray]], alpha: float = 0.05, power: float = POWER) -> float:
    """The detection limit of `score_p` on this recording: the sum of squares of the torque (the
    units of `Stats.yy`) the tested columns must explain for the test to find them at `alpha`
    with probability `power`. Per value searched, from the same block scores (one
    `block_scores` per value): with the blocks' noise spread Ω (the cluster jackknife, as in
    `score_p`) and the columns' information Q = Σ_b Q_b, columns whose coefficients β explain
    βᵀQβ give Wald's statistic the non-centrality βᵀQΩ⁻¹Qβ; the least βᵀQβ that reaches the
    non-centrality λ at which a statistic of k degrees of freedom, its noise estimated from G
    blocks (F with k and G − k), exceeds its level with probability `power` is λ/μ, μ the largest
    eigenvalue of Q^½ Ω⁻¹ Q^½ (the direction this recording sees best). Where a parameter is
    searched, the largest statistic over the values is what is judged: the level is shared among
    them (Bonferroni: an upper bound, neighbouring values being alike). Returns the median over
    the values (a typical value of the searched parameter); inf where none can be tested."""
    out = []
    for x in scores:
        reduced, s = _reduced(x), x[0]
        if reduced is None:
            continue
        k, lam, _, _, _, _, dj, _ = reduced
        half = np.diag(np.sqrt(lam))  # Q^½ in the basis R (Q there is diag(lam))
        mu = float(np.linalg.eigvalsh(half @ np.linalg.pinv(dj.T @ dj) @ half).max())
        if mu > 0:
            out.append(_noncentrality(k, s.shape[0] - k, alpha / len(scores), power) / mu)
    return float(np.median(out)) if out else np.inf


@functools.lru_cache(maxsize=256)
def _noncentrality(k: int, dof: int, alpha: float, power: float) -> float:
    """λ at which a Wald statistic of k degrees of freedom with its noise estimated on `dof`
    (k·F(k, dof), non-central) exceeds its level-`alpha` critical value with probability `power`."""
    from scipy.optimize import brentq

    crit = stats.f.isf(alpha, k, dof)
    gap = lambda lam: stats.ncf.sf(crit, k, dof, lam) - power
    top = 10.0
    while gap(top) < 0 and top < 1e6:
        top *= 4
    return float(brentq(gap, 1e-9, top))


def _solve_psd(omega: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Ω⁻¹ m for a batch of positive semi-definite Ω (B, k, k) and m (B, k) (a tiny ridge where
    Ω is singular)."""
    k = omega.shape[1]
    ridge = (1e-12 * np.trace(omega, axis1=1, axis2=2) + 1e-300)[:, None, None] * np.eye(k)
    return np.linalg.solve(omega + ridge, m[..., None])[..., 0]


def correlation_time(x: np.ndarray, dt: float) -> float:
    """The integrated autocorrelation time of the columns of x (rows, n) [s], the largest: 1 +
    2 Σ ρ_k over the lags up to Sokal's window (five times the running estimate), times dt.
    The variance of a mean over T seconds of such a series is that of T / τ independent values."""
    out = 0.0
    for y in np.asarray(x, float).T:
        y = y - y.mean()
        n = y.size
        if n < 8 or not np.any(y):
            continue
        f = np.fft.rfft(y, 2 * n)
        ac = np.fft.irfft(f * np.conj(f))[:n]
        ac = ac / ac[0]
        taus = 1 + 2 * np.cumsum(ac[1:n // 4])  # the estimate summed up to each lag m = 1, 2, ...
        window = np.flatnonzero(np.arange(1, taus.size + 1) >= 5 * taus)
        tau = taus[window[0]] if window.size else taus[-1]
        out = max(out, tau * dt)
    return out


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
