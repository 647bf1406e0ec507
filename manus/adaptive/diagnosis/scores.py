"""The score test of a candidate's columns (`manus diagnose`): are columns missing from a model?

Per block of rows, the columns' score against the model's residual (`block_scores`); over the
blocks, Wald's statistic with the blocks as clusters, its noise from the cluster jackknife
(`jackknife`), its null distribution from sign flips of the blocks (`score_p`, one-sided in the
columns whose sign physics fixes: `physical`); the size an effect must have to be found
(`detectable`); and how long a residual stays correlated (`correlation_time`: how long the
blocks must be to be nearly independent).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple, cast

import numpy as np
from scipy import stats

from manus.adaptive.identify.lsq import RCOND, Appended, Stats


def block_scores(st: Stats | Appended, test: np.ndarray, blocks: np.ndarray) -> Scores:
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
    test = np.asarray(test, bool)
    if isinstance(st, Appended) and st.tests_appended(test):
        return _appended_scores(st, blocks)
    A, b = st.normal()
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
    return Scores(masks @ (u @ T), (masks @ TA).reshape(masks.shape[0], k, k))


def _appended_scores(st: Appended, blocks: np.ndarray) -> Scores:
    """`block_scores` of exactly the columns appended to `st.base`, from its blocks: the base's fit
    on every row is the same for every set of columns appended to it (`Stats.whole_fit`)."""
    Asum, theta, u0 = st.base.whole_fit()
    B, C, D, bE = st.normal_blocks()
    k = D.shape[-1]
    T0 = -np.linalg.lstsq(Asum.T, C.sum(0).T, rcond=RCOND)[0] if theta.size else np.zeros((0, k))
    masks = np.asarray(blocks, float)
    u = u0 @ T0 + (bE - C @ theta)  # (S, k): the partialled instruments against the model's residual
    TA = (T0.T[None] @ B + D).reshape(D.shape[0], k * k)  # (S, k·k): each segment's Z̃ᵀE
    return Scores(masks @ u, (masks @ TA).reshape(masks.shape[0], k, k))


class Jackknife(NamedTuple):
    """One value's block scores reduced to the directions its columns identify (`jackknife`)."""

    k: int  # how many directions the columns identify
    eigenvalues: np.ndarray  # (k,) of Σ_b Q_b in those directions
    s: np.ndarray  # (G, k) the blocks' scores there (s R)
    Q: np.ndarray  # (G, k, k) the blocks' information there (Rᵀ Q_b R)
    Q_inv: np.ndarray  # (k, k) (Σ_b Rᵀ Q_b R)⁻¹
    L: np.ndarray  # (G, k, k) (I − Q_b Q⁻¹)⁻¹: a block's fit left out of it
    noise: np.ndarray  # (G, k) the blocks' jackknifed noise scores d
    R: np.ndarray  # (K, k) the directions (Q's eigenvectors above rounding)


@dataclass(frozen=True, eq=False)
class Scores:
    """The block scores of `block_scores`: s (G, k) and each block's information Q (G, k, k);
    their `jackknife` worked out once (`score_p` and `detectable` both judge it)."""

    s: np.ndarray
    Q: np.ndarray

    @functools.cached_property
    def jackknife(self) -> Jackknife | None:
        """`jackknife(s, Q)`."""
        return jackknife(self.s, self.Q)


FLIPS = 2000  # sign-flip draws of `score_p` at least (its smallest p: 1/(draws + 1)) ...
FLIPS_PER_ALPHA = 4  # ... and at least this many over the level a p is judged at
FLIP_CHUNK = 250  # draws at a time, at most ...
FLIP_WORK = 4_000_000  # ... and at most this many V·k³ (values searched × cube of the columns) a chunk
MIN_EFFECTIVE_BLOCKS = 12.0  # below this many blocks sharing the information, the exact flips (see score_p)


def jackknife(s: np.ndarray, Q: np.ndarray) -> Jackknife | None:
    """One value's block scores s (G, k) and information Q (G, k, k) reduced to the directions the
    columns identify (R: Q's eigenvectors above rounding); None when nothing is identifiable or the
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
    return Jackknife(k, lam[keep], sr, Qr, Qi, L, dj, R)


def score_p(
    scores: list[Scores], alpha: float = 0.05, seed: int = 0, stop_above: float = 0.1, signed: np.ndarray | None = None
) -> tuple[float, int, str]:
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
    from β̂ to the coefficients the physics allows, in β̂'s precision metric (`physical`: the
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
        j = x.jackknife
        if j is None:
            continue
        omega = j.noise.T @ j.noise
        m = physical(j.s.sum(0)[None, None], j.Q.sum(0)[None], j.Q_inv[None], j.R[None], omega[None, None], signed)[
            0, 0
        ]
        observed[v] = m @ _solve_psd(omega[None], m[None])[0]
        lev = np.einsum("gij,ji->g", j.Q, j.Q_inv)  # each block's share of the information (Σ = k)
        effective = min(effective, j.k * j.k / max(float(np.sum(lev**2)), 1e-300))
        prepared.append(j)
    if not prepared:
        return 1.0, 0, "none"
    # the blocks' noise scores flipped where many blocks share the information (the wild
    # bootstrap's power); the scores themselves where a few hold most of it (an exact
    # randomization test: the noise of those few cannot be told from their signal)
    wild = effective >= MIN_EFFECTIVE_BLOCKS
    by_k: dict[int, list[Jackknife]] = {}  # the values, grouped by how many identifiable directions they have
    for j in prepared:
        by_k.setdefault(j.k, []).append(j)
    G = scores[0].s.shape[0]
    # A draw's pseudo-scores are w_b d_b (d: the jackknifed noise scores, or the scores s
    # themselves for the exact flips, signs flipped); its statistic is computed from them as from
    # the data: m = Σ w d, β = Q⁻¹ m, the blocks' jackknifed scores e_b = L_b (w_b d_b − Q_b β) =
    # w_b d2_b − Q2_b β (d2 = L d, Q2 = L Q) and their spread Ω = Σ e eᵀ (`_Spread`), per k the
    # values stacked
    pre = []
    for k, vals in by_k.items():
        d = np.stack([j.noise if wild else j.s for j in vals])  # (V, G, k)
        Qi = np.stack([j.Q_inv for j in vals])
        Qs, R = np.stack([j.Q.sum(0) for j in vals]), np.stack([j.R for j in vals])
        spread = _Spread(np.stack([j.L for j in vals]), d, np.stack([j.Q for j in vals]))
        # least squares' information is symmetric: there the projection on the physical cone is one
        # in the statistic's own metric, and never lengthens it (with instruments it may)
        symmetric = bool(np.all(np.abs(Qs - np.swapaxes(Qs, 1, 2)) <= 1e-9 * np.abs(Qs).max()))
        pre.append((k, len(vals), d.transpose(1, 0, 2).reshape(G, -1), Qi, spread, Qs, R, symmetric))
    best = int(np.argmax(observed))
    rng = np.random.default_rng(seed)
    exceed = done = 0
    per_draw = sum(V * k**3 for k, V, *_ in pre)  # a draw's work, in the units of FLIP_WORK
    chunk = int(np.clip(FLIP_WORK // max(per_draw, 1), 1, FLIP_CHUNK))  # (an early stop is checked between chunks)
    while done < draws:
        n = min(chunk, draws - done)
        w = rng.choice((-1.0, 1.0), size=(n, G))
        top = np.full(n, -np.inf)
        for k, V, dflat, Qi, spread, Qs, R, symmetric in pre:
            m = (w @ dflat).reshape(n, V, k)
            omega = spread(w, (Qi[None] @ m[..., None])[..., 0])
            if signed is not None and symmetric:
                # the physical statistic is at most Wald's where the projection on the cone (through 0)
                # is in the statistic's own metric: only the draws whose Wald statistic reaches the
                # observed one can count
                W = _wald(m, omega)
                near = W.max(1) >= observed[best] * (1 - 1e-6)
                if near.any():
                    W[near] = _wald(physical(m[near], Qs, Qi, R, omega[near], signed), omega[near])
            else:
                W = _wald(physical(m, Qs, Qi, R, omega, signed), omega)
            top = np.maximum(top, W.max(1))
        exceed += int(np.sum(top >= observed[best] * (1 - 1e-9)))
        done += n
        if (1 + exceed) / (1 + draws) > stop_above:  # surely above it, whatever the rest would give
            break
    return (1 + exceed) / (1 + done), best, "wild" if wild else "exact"


class _Spread:
    """The spread Ω = Σ_b e_b e_bᵀ of a draw's jackknifed block scores e_b = w_b d2_b − Q2_b β (d2 =
    L d, Q2 = L Q), for draws w (n, G) and their β (n, V, k): (n, V, k, k). With few columns, from
    sums over the blocks worked out once, Ω = D − T·β − (T·β)ᵀ + S·β·β (D = Σ d2 d2ᵀ, T = Σ w_b d2_b ⊗
    Q2_b, S = Σ Q2_b ⊗ Q2_b: a draw costs G·V·k³ in one matrix product); with many (`OUTER_K`),
    from the e_b themselves (2·G·V·k², in small products, slower per operation)."""

    OUTER_K = 10

    def __init__(self, L: np.ndarray, d: np.ndarray, Q: np.ndarray):
        V, G, k = d.shape
        d2, Q2 = (L @ d[..., None])[..., 0], L @ Q  # (V, G, k), (V, G, k, k)
        self.outer = k >= self.OUTER_K
        if self.outer:
            self.d2, self.Q2 = d2, Q2.reshape(V, G * k, k)
            return
        self.D = np.einsum("vgi,vgj->vij", d2, d2)
        self.T = np.einsum("vgi,vgjl->gvijl", d2, Q2).reshape(G, -1)
        self.S = np.einsum("vgil,vgjm->vlmij", Q2, Q2).reshape(V, k * k, k * k)

    def __call__(self, w: np.ndarray, beta: np.ndarray) -> np.ndarray:
        n, V, k = beta.shape
        if self.outer:
            G = w.shape[1]
            e = w[:, None, :, None] * self.d2[None] - (self.Q2[None] @ beta[..., None]).reshape(n, V, G, k)
            return np.swapaxes(e, 2, 3) @ e
        tb = ((w @ self.T).reshape(n, V, k * k, k) @ beta[..., None]).reshape(n, V, k, k)
        bb = (beta[..., :, None] * beta[..., None, :]).reshape(n, V, 1, k * k)
        return self.D[None] - tb - tb.transpose(0, 1, 3, 2) + (bb @ self.S[None]).reshape(n, V, k, k)


def physical(
    m: np.ndarray, Qs: np.ndarray, Qi: np.ndarray, R: np.ndarray, omega: np.ndarray, signed: np.ndarray | None
) -> np.ndarray:
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
    S = R[None] @ Ainv @ np.swapaxes(R, 1, 2)[None]  # the columns' coefficients' covariance
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


def detectable(scores: list[Scores], alpha: float = 0.05, power: float = POWER) -> float:
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
        j = x.jackknife
        if j is None:
            continue
        half = np.diag(np.sqrt(j.eigenvalues))  # Q^½ in the basis R (Q there is diag(eigenvalues))
        mu = float(np.linalg.eigvalsh(half @ np.linalg.pinv(j.noise.T @ j.noise) @ half).max())
        if mu > 0:
            out.append(_noncentrality(j.k, x.s.shape[0] - j.k, alpha / len(scores), power) / mu)
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
    return float(cast(float, brentq(gap, 1e-9, top)))


def _wald(m: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """mᵀ Ω⁻¹ m for summed scores m (n, V, k) and their spreads Ω (n, V, k, k): (n, V)."""
    n, V, k = m.shape
    return np.sum(m * _solve_psd(omega.reshape(-1, k, k), m.reshape(-1, k)).reshape(n, V, k), axis=2)


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
        taus = 1 + 2 * np.cumsum(ac[1 : n // 4])  # the estimate summed up to each lag m = 1, 2, ...
        window = np.flatnonzero(np.arange(1, taus.size + 1) >= 5 * taus)
        tau = taus[window[0]] if window.size else taus[-1]
        out = max(out, float(tau * dt))
    return out
