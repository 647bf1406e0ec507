"""The score test of `manus diagnose` (`manus.adaptive.diagnosis.scores.block_scores`, `score_p`,
`correlation_time`) against independent references: the Frisch–Waugh–Lovell theorem (numpy's
least squares of the full model), a direct loop over the sign flips, the closed form of an AR(1)
process's integrated autocorrelation time, and its size and power on simulated data whose truth
is known."""

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from manus.adaptive.diagnosis import scores as score_test
from manus.adaptive.identify.lsq import Stats


def _design(rng, rows=600, n=2, p=3, k=2):
    X = rng.normal(size=(rows, n, p))
    E = rng.normal(size=(rows, n, k)) + 0.5 * X[:, :, :1]  # correlated with the model's columns
    return X, E


def _segments(rows, G):
    starts = np.linspace(0, rows, G + 1).astype(int)[:-1]
    return starts, np.eye(G, dtype=bool)  # one segment per block


def test_block_scores_are_the_partialled_scores_and_recover_the_full_fit():
    """Σ_b s_b = Z̃ᵀ r0 and Q⁻¹ Σ_b s_b is the tested columns' coefficient in the least-squares
    fit of the full model (Frisch–Waugh–Lovell), computed here by numpy on the rows."""
    rng = np.random.default_rng(0)
    X, E = _design(rng)
    tau = X @ np.array([1.0, -2.0, 0.5]) + E @ np.array([0.3, -0.1]) + 0.1 * rng.normal(size=X.shape[:2])
    starts, blocks = _segments(X.shape[0], 10)
    st = Stats.of(np.concatenate([X, E], 2), tau, starts)
    sc = score_test.block_scores(st, np.array([False, False, False, True, True]), blocks)
    s, Q = sc.s, sc.Q
    full = np.linalg.lstsq(np.concatenate([X, E], 2).reshape(-1, 5), tau.ravel(), rcond=None)[0]
    beta = np.linalg.solve(Q.sum(0), s.sum(0)) / st.scale[3:]  # (Stats scales its columns)
    assert beta == pytest.approx(full[3:], rel=1e-9)
    # the restricted residual's product with the partialled columns, block by block
    Xf, Ef, y = X.reshape(-1, 3), E.reshape(-1, 2), tau.ravel()
    r0 = y - Xf @ np.linalg.lstsq(Xf, y, rcond=None)[0]
    Et = (Ef - Xf @ np.linalg.lstsq(Xf, Ef, rcond=None)[0]) / st.scale[3:]
    rows = np.repeat(np.arange(X.shape[0]), 2)
    per_block = np.array(
        [
            Et[(rows >= a) & (rows < b)].T @ r0[(rows >= a) & (rows < b)]
            for a, b in zip(starts, np.r_[starts[1:], X.shape[0]], strict=True)
        ]
    )
    assert s == pytest.approx(per_block, rel=1e-8, abs=1e-10)


@pytest.mark.parametrize("route", ["sums", "outer"])
@pytest.mark.parametrize("mode", ["wild", "exact"])
def test_the_flips_fast_algebra_equals_the_statistic_computed_again(mode, route, monkeypatch):
    """Each draw's Ω is expanded algebraically (D − T·β − (T·β)ᵀ + S·β·β) or summed from the
    draw's jackknifed block scores; a loop that flips the blocks' jackknifed noise scores (wild)
    or the scores themselves (exact) and recomputes W from them from scratch (refit, jackknife,
    Ω) counts the same exceedances."""
    monkeypatch.setattr(score_test, "MIN_EFFECTIVE_BLOCKS", 0.0 if mode == "wild" else np.inf)
    monkeypatch.setattr(score_test._Spread, "OUTER_K", 1 if route == "outer" else 99)
    rng = np.random.default_rng(1)
    G, k = 12, 3
    scores = []
    for _ in range(4):  # four values of a searched parameter
        A = rng.normal(size=(G, k, k))
        scores.append(score_test.Scores(rng.normal(size=(G, k)), np.einsum("gij,gkj->gik", A, A)))

    def jackknifed(s, Q):  # each block's score with the fit left out of it
        Qi = np.linalg.inv(Q.sum(0))
        d = s - Q @ (Qi @ s.sum(0))
        return np.stack([np.linalg.solve(np.eye(k) - Q[b] @ Qi, d[b]) for b in range(G)])

    def wald(s, Q):
        d = jackknifed(s, Q)
        return s.sum(0) @ np.linalg.solve(d.T @ d, s.sum(0))

    observed = max(wald(x.s, x.Q) for x in scores)
    flipped = [jackknifed(x.s, x.Q) if mode == "wild" else x.s for x in scores]  # a draw: w_b times these
    w = np.random.default_rng(0).choice((-1.0, 1.0), size=(score_test.FLIPS, G))  # the draws score_p makes
    exceed = sum(
        max(wald(wi[:, None] * d, x.Q) for d, x in zip(flipped, scores, strict=True)) >= observed * (1 - 1e-9)
        for wi in w
    )
    p, _, how = score_test.score_p(scores, alpha=0.5, stop_above=2.0)
    assert how == mode
    assert p == pytest.approx((1 + exceed) / (1 + score_test.FLIPS), abs=1e-12)


@pytest.mark.parametrize("skew", [0.0, 0.3], ids=["least squares", "instruments"])
@pytest.mark.parametrize("shift", [0.0, 0.6], ids=["null", "an effect"])
def test_the_one_sided_flips_count_as_every_draw_projected(shift, skew):
    """With least squares (each block's information Q symmetric) the flips project a draw on the
    physical cone only where its Wald statistic reaches the observed one (a projection on a cone
    through 0, in the statistic's own metric, never lengthens it); with instruments (Q not
    symmetric, the projection's metric not the statistic's) every draw. A loop that projects
    every draw (`physical`) and computes its statistic from the draw's jackknifed block scores
    counts the same exceedances; the unprojected Wald statistic would count otherwise."""
    rng = np.random.default_rng(7)
    G, k = 16, 2
    signed = np.array([True, True])
    scores = []
    for _ in range(3):  # three values of a searched parameter
        A = rng.normal(size=(G, k, k))
        Q = np.einsum("gij,gkj->gik", A, A) + skew * np.array([[0.0, -1.0], [1.0, 0.0]])  # (IV: ZᵀX, not XᵀX)
        scores.append(score_test.Scores(rng.normal(size=(G, k)) + shift, Q))
    js = [x.jackknife for x in scores]
    assert all(j is not None and j.k == k for j in js)

    def statistics(w, projected):  # each value's statistic of the draw w (None: the data's scores)
        out = []
        for j in js:
            d = j.s if w is None else w[:, None] * (j.noise if wild else j.s)
            m = d.sum(0)
            beta = j.Q_inv @ m
            e = np.stack([j.L[b] @ (d[b] - j.Q[b] @ beta) for b in range(G)]) if w is not None else j.noise
            omega = e.T @ e
            if projected:
                m = score_test.physical(
                    m[None, None], j.Q.sum(0)[None], j.Q_inv[None], j.R[None], omega[None, None], signed
                )[0, 0]
            out.append(m @ np.linalg.solve(omega + 1e-12 * np.trace(omega) * np.eye(k), m))
        return max(out)

    effective = min(j.k**2 / np.sum(np.einsum("gij,ji->g", j.Q, j.Q_inv) ** 2) for j in js)
    wild = effective >= score_test.MIN_EFFECTIVE_BLOCKS
    observed = statistics(None, True)
    w = np.random.default_rng(0).choice((-1.0, 1.0), size=(score_test.FLIPS, G))  # the draws score_p makes
    drawn = [statistics(wi, True) for wi in w]
    exceed = sum(x >= observed * (1 - 1e-9) for x in drawn)
    wald = sum(statistics(wi, False) >= observed * (1 - 1e-9) for wi in w)
    p, _, _ = score_test.score_p(scores, alpha=0.5, stop_above=2.0, signed=signed)
    assert p == pytest.approx((1 + exceed) / (1 + score_test.FLIPS), abs=1e-12)
    assert exceed > 0 and exceed != wald  # (draws the projection decides, on both sides)


def _null_case(rng, G=40, heavy=40, beta=0.0):
    """Blocks of unequal information (the tested column 10x larger in the first `heavy` blocks),
    noise whose level differs between blocks; the tested column's coefficient `beta`."""
    rows, n = 40 * G, 1
    X = rng.normal(size=(rows, n, 2))
    weight = np.full(rows, 0.3)
    weight[: rows // G * heavy] = 3.0
    E = (rng.normal(size=(rows, n)) * weight[:, None])[..., None]
    noise = rng.normal(size=(rows, n)) * np.repeat(rng.uniform(0.5, 2.0, G), rows // G)[:, None]
    tau = X @ np.array([1.0, 0.5]) + beta * E[..., 0] + noise
    starts, blocks = _segments(rows, G)
    st = Stats.of(np.concatenate([X, E], 2), tau, starts)
    return score_test.block_scores(st, np.array([False, False, True]), blocks)


@pytest.mark.parametrize("heavy", [2, 6, 12, 40], ids=lambda h: f"{h}-of-40-blocks")
def test_the_score_test_holds_its_size_under_the_null(heavy):
    """300 null data sets, the tested column living in `heavy` of 40 blocks (10x the others'
    amplitude), the noise level different in every block: p < 0.02 in about 2 % of them (the
    wild bootstrap alone gave 11 % with 2 heavy blocks and 4 % with 6; under 12 effective blocks
    the exact flips are used)."""
    rng = np.random.default_rng(11)
    ps = np.array(
        [score_test.score_p([_null_case(rng, heavy=heavy)], alpha=0.02, stop_above=1.0)[0] for _ in range(300)]
    )
    assert np.mean(ps < 0.02) <= 0.045 and 0.04 <= np.mean(ps < 0.1) <= 0.17, (np.mean(ps < 0.02), np.mean(ps < 0.1))


@pytest.mark.parametrize("heavy", [6, 40], ids=lambda h: f"{h}-of-40-blocks")
def test_the_one_sided_score_test_holds_its_size_and_judges_by_the_sign(heavy):
    """A column whose coefficient physics keeps ≥ 0 (`signed`): under the null, p < 0.02 in
    about 2 % of 300 data sets (exact flips with 6 heavy blocks, wild ones with 40); with the
    effect at the physical sign, its p is about half the two-sided one (one column: a one-sided
    test), and at the wrong sign nothing is found."""
    rng = np.random.default_rng(12)
    signed = np.array([True])
    ps = np.array(
        [
            score_test.score_p([_null_case(rng, heavy=heavy)], alpha=0.02, stop_above=1.0, signed=signed)[0]
            for _ in range(300)
        ]
    )
    assert np.mean(ps < 0.02) <= 0.045 and 0.04 <= np.mean(ps < 0.1) <= 0.17, (np.mean(ps < 0.02), np.mean(ps < 0.1))
    ratios = []
    for _ in range(20):
        x = _null_case(rng, heavy=heavy, beta=0.02 if heavy == 40 else 0.06)
        two = score_test.score_p([x], alpha=0.01, stop_above=1.0)[0]
        one = score_test.score_p([x], alpha=0.01, stop_above=1.0, signed=signed)[0]
        assert one <= two + 1e-12 or one == 1.0  # (the fitted coefficient's sign: physical, or not)
        if 0.003 < two < 0.5:  # (above the flips' floor)
            ratios.append(one / two)
        wrong = (
            score_test.Scores(x.s * -1, x.Q) if heavy == 40 else None
        )  # (the scores' sign turned: the effect's opposite)
        if wrong is not None and two < 0.01:
            assert score_test.score_p([wrong], alpha=0.01, stop_above=1.0, signed=signed)[0] > 0.3
    assert len(ratios) >= 5 and 0.35 <= np.median(ratios) <= 0.65, ratios


def test_an_effect_spread_over_the_blocks_is_found_and_one_in_two_blocks_is_judged_by_them(monkeypatch):
    """With the effect in every block the wild flips find it. With most of the column's
    information in two blocks of forty the exact flips judge it, and their p is larger than the
    wild bootstrap's on the same data (whose size fails there, see above)."""
    rng = np.random.default_rng(3)
    p, _, how = score_test.score_p([_null_case(rng, heavy=40, beta=0.3)], alpha=0.01)
    assert how == "wild" and p < 0.01
    scores = [_null_case(rng, heavy=2, beta=0.3)]
    p, _, how = score_test.score_p(scores, alpha=0.01)
    monkeypatch.setattr(score_test, "MIN_EFFECTIVE_BLOCKS", 0.0)
    p_wild, _, _ = score_test.score_p(scores, alpha=0.01)
    assert how == "exact" and p > p_wild


def test_correlation_time_of_an_ar1_process():
    """x_t = ρ x_{t−1} + e_t: the integrated autocorrelation time is (1 + ρ)/(1 − ρ) samples."""
    rng = np.random.default_rng(4)
    rho, n = 0.8, 200_000
    e = rng.normal(size=n)
    x = np.empty(n)
    x[0] = e[0]
    for t in range(1, n):
        x[t] = rho * x[t - 1] + e[t]
    assert score_test.correlation_time(x[:, None], 0.01) == pytest.approx(0.01 * (1 + rho) / (1 - rho), rel=0.1)


def test_nothing_to_test_gives_p_one():
    """A candidate whose columns all vanish (or are the model's own) has no score: p = 1."""
    rng = np.random.default_rng(5)
    X, _ = _design(rng)
    starts, blocks = _segments(X.shape[0], 10)
    st = Stats.of(np.concatenate([X, X[:, :, :1]], 2), rng.normal(size=X.shape[:2]), starts)
    assert score_test.score_p([score_test.block_scores(st, np.array([False, False, False, True]), blocks)])[0] == 1.0
    assert score_test.score_p([score_test.block_scores(st, np.zeros(4, bool), blocks)])[0] == 1.0


def _lambda_closed_form(k, dof, alpha, power):
    """The non-centrality of an F(k, dof) test at `alpha` with `power`, from scipy by bisection
    (independent of the score test's root finder)."""
    from scipy import stats

    crit = stats.f.isf(alpha, k, dof)
    lo, hi = 0.0, 1000.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if stats.ncf.sf(crit, k, dof, mid) < power else (lo, mid)
    return lo


@pytest.mark.parametrize("k", [1, 2])
def test_the_detection_limit_is_the_closed_form_for_white_noise(k):
    """White noise of variance σ² in every row, 200 blocks: the blocks' noise spread is σ²Q, so
    the sum of squares a column set must explain to be found 4 times in 5 is λ σ² (λ the
    non-centrality at which an F(k, G − k) test at α has power 0.8), whatever the columns."""
    rng = np.random.default_rng(21)
    G, sigma = 200, 0.7
    rows = 40 * G
    X = rng.normal(size=(rows, 1, 2))
    E = rng.normal(size=(rows, 1, k)) * 3.0 + X[:, :, :1]
    tau = X @ np.array([1.0, 0.5]) + sigma * rng.normal(size=(rows, 1))
    starts, blocks = _segments(rows, G)
    st = Stats.of(np.concatenate([X, E], 2), tau, starts)
    scores = [score_test.block_scores(st, np.r_[False, False, [True] * k], blocks)]
    assert score_test.detectable(scores, alpha=0.01) == pytest.approx(
        _lambda_closed_form(k, G - k, 0.01, 0.8) * sigma**2, rel=0.15
    )


def test_an_effect_at_the_detection_limit_is_found_four_times_in_five():
    """200 data sets of 40 blocks with a noise level different in every block: the effect's
    coefficient set so that it explains the detection limit computed on its data without it; the
    score test (sign flips, not the F approximation) finds it in about 80 % of them."""
    rng = np.random.default_rng(22)
    G, rows, hits, trials = 40, 1600, 0, 200
    starts, blocks = _segments(rows, G)
    for _ in range(trials):
        X = rng.normal(size=(rows, 1, 2))
        E = rng.normal(size=(rows, 1, 1)) + 0.5 * X[:, :, :1]
        noise = rng.normal(size=(rows, 1)) * np.repeat(rng.uniform(0.5, 2.0, G), rows // G)[:, None]
        base = X @ np.array([1.0, 0.5])
        test = np.array([False, False, True])
        null = Stats.of(np.concatenate([X, E], 2), base + noise, starts)
        ss = score_test.detectable([score_test.block_scores(null, test, blocks)], alpha=0.05)
        Xf, Ef = X.reshape(-1, 2), E.reshape(-1, 1)
        partialled = Ef - Xf @ np.linalg.lstsq(Xf, Ef, rcond=None)[0]
        beta = np.sqrt(ss / np.sum(partialled**2))
        st = Stats.of(np.concatenate([X, E], 2), base + beta * E[..., 0] + noise, starts)
        hits += score_test.score_p([score_test.block_scores(st, test, blocks)], alpha=0.05, stop_above=0.06)[0] < 0.05
    print("power at the limit", hits / trials)
    assert 0.7 <= hits / trials <= 0.9, hits / trials


def test_simes_combination_of_the_two_tests():
    """A candidate's p from its score test and its held-out errors (`significance.combined`) is
    Simes' rule: min(2 p₍₁₎, p₍₂₎); one test alone is its own p. Its level holds for two
    one-sided tests that rise and fall together (positively correlated normal statistics, the
    dependence the two tests computed from one residual have): the share of null draws it
    rejects at 0.05 stays within sampling error of 0.05 or under it (numpy's normal draws; at
    independence the closed form is exactly α: both under α, α², or one under α/2 and the other
    over α, 2 (α/2)(1 − α)), while it rejects more often than Bonferroni's doubled minimum when
    both see the same effect."""
    from scipy import stats

    from manus.adaptive.diagnosis.significance import combined

    assert combined({"score": 0.004, "held_out": 0.005}) == pytest.approx(0.005)
    assert combined({"score": 0.001, "held_out": 0.5}) == pytest.approx(0.002)
    assert combined({"held_out": 0.03}) == pytest.approx(0.03)
    assert combined({"score": 0.7, "held_out": 0.9}) == pytest.approx(0.9)
    rng = np.random.default_rng(0)
    alpha = 0.05
    for rho in (0.0, 0.5, 0.9, 0.99):
        z = rng.normal(size=(400_000, 2))
        z[:, 1] = rho * z[:, 0] + np.sqrt(1 - rho**2) * z[:, 1]
        p = stats.norm.sf(z)
        ps = np.sort(p, axis=1)
        simes = np.minimum(2 * ps[:, 0], ps[:, 1])
        size = float(np.mean(simes < alpha))
        assert size < alpha + 3 * np.sqrt(alpha * (1 - alpha) / z.shape[0])
        # the draws are the function's own rule
        k = np.flatnonzero(simes < alpha)[:20]
        assert [combined({"score": a, "held_out": b}) for a, b in p[k]] == pytest.approx(simes[k].tolist())
    # positively dependent, both tests see the same effect: more power than the doubled minimum
    z = rng.normal(size=(200_000, 2)) * 0.3 + 2.7
    p = stats.norm.sf(z)
    bonferroni = np.mean(2 * p.min(1) < alpha / 9)
    simes = np.mean(np.minimum(2 * p.min(1), p.max(1)) < alpha / 9)
    assert simes > bonferroni


def test_the_one_sided_statistic_is_the_distance_to_the_physical_cone():
    """`scores.physical` for a spring on top of its preload (two correlated columns, the stiffness
    signed): Wald's statistic minus the squared distance, in β̂'s precision metric, from β̂ to
    the coefficients with a stiffness ≥ 0, against scipy's bounded least squares; Wald's own
    where β̂ has the physical sign."""
    rng = np.random.default_rng(5)
    signed = np.array([False, True])
    for _ in range(20):
        B = rng.normal(size=(2, 2)) + np.array([[3.0, 2.5], [0.0, 1.0]])  # (correlated directions)
        Qs = B @ B.T
        R = np.linalg.qr(rng.normal(size=(2, 2)))[0]  # the identified directions (a rotation)
        omega = np.diag(rng.uniform(0.5, 2.0, 2))
        m = rng.normal(size=2) * 3
        got = score_test.physical(m[None, None], Qs[None], np.linalg.inv(Qs)[None], R[None], omega[None, None], signed)[
            0, 0
        ]
        W_plus = got @ np.linalg.solve(omega, got)
        b = R @ np.linalg.solve(Qs, m)  # β̂ in the columns
        A = R @ Qs @ np.linalg.inv(omega) @ Qs @ R.T  # its precision there
        L = np.linalg.cholesky(A).T
        ref = lsq_linear(L, L @ b, bounds=([-np.inf, 0.0], [np.inf, np.inf]), method="bvls", tol=1e-14).x
        expected = b @ A @ b - (b - ref) @ A @ (b - ref)
        np.testing.assert_allclose(W_plus, expected, rtol=1e-8, atol=1e-10)
        if b[1] >= 0:
            np.testing.assert_allclose(W_plus, m @ np.linalg.solve(omega, m), rtol=1e-10)
