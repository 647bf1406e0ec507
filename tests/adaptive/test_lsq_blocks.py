"""Appended statistics (`lsq.Stats.extend` -> `lsq.Appended`): a fit on segment masks solved by
the base's factorisation and the appended columns' Schur complement, checked against numpy's
least squares (and instrumental variables) on the rows themselves, bounds against scipy's bounded
least squares, and a rank-deficient appended column against the minimum-norm solution."""

import numpy as np
from scipy.optimize import lsq_linear

from manus.adaptive.diagnosis.scores import block_scores
from manus.adaptive.identify import lsq

SEG = 50


def _problem(seed, rows=3000, n=2, P0=6, k=3, V=4):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(rows, n, P0)) * rng.uniform(0.1, 10, P0)
    E = rng.normal(size=(V, rows, n, k)) * rng.uniform(0.5, 5, (V, 1, 1, k))
    tau = X @ rng.normal(size=P0) + E[0] @ np.array([0.7, -0.4, 0.2])[:k] + 0.3 * rng.normal(size=(rows, n))
    starts = np.arange(0, rows, SEG)
    masks = rng.random((5, starts.size)) < 0.7
    return X, E, tau, starts, masks


def _rows(mask):
    return np.repeat(mask, SEG)


def _scaled(Y):
    return Y / np.sqrt(np.mean(Y**2, axis=(0, 1)))


def test_appended_fits_are_least_squares_on_the_rows():
    X, E, tau, starts, masks = _problem(0)
    every = lsq.Stats.of(X, tau, starts).extend(E)
    C = every.coefs(masks)
    errs = every.sses(C, masks)
    for v in range(E.shape[0]):
        Y = _scaled(np.concatenate([X, E[v]], 2))
        for f, m in enumerate(masks):
            A, y = Y[_rows(m)].reshape(-1, Y.shape[2]), tau[_rows(m)].reshape(-1)
            ref = np.linalg.lstsq(A, y, rcond=None)[0]
            np.testing.assert_allclose(C[v, f], ref, rtol=1e-9, atol=1e-12)
            np.testing.assert_allclose(errs[v, f], np.sum((y - A @ ref) ** 2), rtol=1e-9)
            one = every.one(v)  # (one value: the same fit)
            np.testing.assert_allclose(one.coefs(m[None])[0], ref, rtol=1e-9, atol=1e-12)


def test_appended_bounded_fits_match_scipys_bounded_least_squares():
    X, E, tau, starts, masks = _problem(1)
    tau = tau - 1.5 * E[1][..., 1]  # the second appended column's coefficient below its bound 0 (value 1)
    every = lsq.Stats.of(X, tau, starts).extend(E)
    lower = np.r_[np.full(X.shape[2], -np.inf), np.zeros(E.shape[3])]
    C = every.coefs(masks, lower)
    for v in range(E.shape[0]):
        Yr = np.concatenate([X, E[v]], 2)
        scale = np.sqrt(np.mean(Yr**2, axis=(0, 1)))
        for f, m in enumerate(masks):
            A, y = (Yr / scale)[_rows(m)].reshape(-1, Yr.shape[2]), tau[_rows(m)].reshape(-1)
            ref = lsq_linear(A, y, bounds=(lower, np.inf), method="bvls", tol=1e-12).x
            np.testing.assert_allclose(C[v, f], ref, rtol=1e-7, atol=1e-9)
    assert np.all(C[1, :, X.shape[2] + 1] == 0)  # held at its bound


def test_appended_instrumental_variables_solve_the_instruments_equations():
    X, E, tau, starts, masks = _problem(2)
    rng = np.random.default_rng(5)
    Z, Ez = X + 0.2 * rng.normal(size=X.shape), E + 0.2 * rng.normal(size=E.shape)
    every = lsq.Stats.of(X, tau, starts, Z).extend(E, Ez)
    C = every.coefs(masks)
    for v in range(E.shape[0]):
        Y, W = _scaled(np.concatenate([X, E[v]], 2)), _scaled(np.concatenate([Z, Ez[v]], 2))
        for f, m in enumerate(masks):
            A, Zr, y = Y[_rows(m)].reshape(-1, Y.shape[2]), W[_rows(m)].reshape(-1, Y.shape[2]), tau[_rows(m)].ravel()
            ref = np.linalg.solve(Zr.T @ A, Zr.T @ y)
            np.testing.assert_allclose(C[v, f], ref, rtol=1e-8, atol=1e-11)


def test_an_appended_column_the_base_explains_gets_the_minimum_norm_solution():
    """A value whose column repeats one of the base's: the whole matrix is singular, and the fit is
    the minimum-norm least-squares solution (the pseudo-inverse's), as the base alone would give."""
    X, E, tau, starts, masks = _problem(3, k=1, V=2)
    E[1] = X[..., :1] * 2.0  # the second value repeats the first base column
    every = lsq.Stats.of(X, tau, starts).extend(E)
    C = every.coefs(masks)
    Y = _scaled(np.concatenate([X, E[1]], 2))
    for f, m in enumerate(masks):
        A, y = Y[_rows(m)].reshape(-1, Y.shape[2]), tau[_rows(m)].reshape(-1)
        ref = np.linalg.lstsq(A, y, rcond=1e-6)[0]
        np.testing.assert_allclose(C[1, f], ref, rtol=1e-6, atol=1e-9)
        assert abs(C[1, f, 0] - C[1, f, -1]) < 1e-8 * abs(C[1, f, 0])  # (the two equal columns share the weight)


def test_scores_of_appended_columns_are_the_whole_statistics_scores():
    """`scores.block_scores` of the appended columns from their blocks equals that of the same
    columns in statistics built whole (least squares and instrumental variables)."""
    X, E, tau, starts, masks = _problem(4, V=2)
    rng = np.random.default_rng(6)
    Z, Ez = X + 0.2 * rng.normal(size=X.shape), E + 0.2 * rng.normal(size=E.shape)
    test = np.r_[np.zeros(X.shape[2], bool), np.ones(E.shape[3], bool)]
    for iv in (False, True):
        every = lsq.Stats.of(X, tau, starts, Z if iv else None).extend(E, Ez if iv else None)
        for v in range(E.shape[0]):
            whole = lsq.Stats.of(
                np.concatenate([X, E[v]], 2), tau, starts, np.concatenate([Z, Ez[v]], 2) if iv else None
            )
            got, ref = block_scores(every.one(v), test, masks), block_scores(whole, test, masks)
            np.testing.assert_allclose(got.s, ref.s, rtol=1e-9, atol=1e-9 * np.abs(ref.s).max())
            np.testing.assert_allclose(got.Q, ref.Q, rtol=1e-9, atol=1e-9 * np.abs(ref.Q).max())


def test_a_fit_asked_for_again_is_the_same_and_a_callers_change_does_not_reach_it():
    X, E, tau, starts, masks = _problem(4)
    every = lsq.Stats.of(X, tau, starts).extend(E)
    lower = np.r_[np.full(X.shape[2], -np.inf), np.zeros(E.shape[3])]
    first = every.coefs(masks, lower)
    first[...] = np.nan  # (a caller writing into what it was given)
    again, free = every.coefs(masks, lower), every.coefs(masks)
    fresh = lsq.Stats.of(X, tau, starts).extend(E)
    np.testing.assert_array_equal(again, fresh.coefs(masks, lower))
    np.testing.assert_array_equal(free, fresh.coefs(masks))
    assert not np.array_equal(again, free)  # (the bounds are part of what is asked)


def _pinv_bounded(M, r, low, hermitian):
    """The bounded solution of one M c = r by numpy's pseudo-inverse (its SVD, cut at `RCOND`),
    coefficients below their bound held there one more at a time (`lsq._bounded`'s rule)."""
    pinv = lambda m: np.linalg.pinv(m, rcond=lsq.RCOND, hermitian=hermitian)
    c, held = pinv(M) @ r, np.zeros(r.size, bool)
    while ((low > c) & ~held).any():
        held |= low > c
        x, free = np.where(held, low, 0.0), (~held).astype(float)
        c = np.where(held, low, pinv(M * np.outer(free, free)) @ ((r - M @ x) * free))
    return c


def test_solutions_near_the_cut_are_the_pseudo_inverses():
    """Matrices whose smallest singular value is just above `RCOND` times the largest (solved as
    the inverse) and just below it (the pseudo-inverse leaves it out), with bounds that bind: the
    solutions are numpy's pseudo-inverse's, least squares (symmetric) and instruments alike."""
    rng = np.random.default_rng(7)
    P, per = 8, 6
    for iv in (False, True):
        Ms, rs = [], []
        for smallest in (1e-8, 3e-10, 3e-11, 1e-13):
            for _ in range(per):
                s = np.geomspace(1.0, smallest, P)
                U = np.linalg.qr(rng.normal(size=(P, P)))[0]
                V = np.linalg.qr(rng.normal(size=(P, P)))[0] if iv else U
                Ms.append((U * s) @ V.T)
                rs.append(U @ rng.normal(size=P))
        if iv:  # invertible, but not once its last coordinate is held at its bound: checked again then
            m = np.zeros((P, P))
            m[: P - 2, : P - 2] = rng.normal(size=(P - 2, P - 2)) + 4 * np.eye(P - 2)
            m[P - 2, P - 1] = m[P - 1, P - 2] = 1.0
            Ms.append(m)
            rs.append(np.r_[rng.normal(size=P - 2), -1.0, 0.5])
        M, r = np.array(Ms), np.array(rs)
        low = np.r_[np.full(P - 3, -np.inf), np.zeros(3)]
        C = lsq._bounded(M, r, low, iv)
        # right-hand sides broadcast over the matrices: each the same as alone
        both = lsq._bounded(M, np.stack([r, 2 * r]), low, iv)
        np.testing.assert_allclose(both[0], C, rtol=1e-12, atol=0)
        np.testing.assert_allclose(both[1], lsq._bounded(M, 2 * r, low, iv), rtol=1e-12, atol=0)
        for m, rr, c in zip(M, r, C, strict=True):
            ref = _pinv_bounded(m, rr, low, hermitian=not iv)
            # (near the cut the solution is determined to about its condition number times rounding)
            np.testing.assert_allclose(c, ref, rtol=0, atol=1e-4 * np.abs(ref).max())
            assert np.all(c >= low)
            if not iv:  # the objective c'Mc - 2 r'c, which the ill-determined directions barely move
                here, there = (x @ m @ x - 2 * rr @ x for x in (c, ref))
                assert abs(here - there) <= 1e-7 * max(abs(there), 1.0)
