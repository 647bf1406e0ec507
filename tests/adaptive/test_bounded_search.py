"""The search of a non-linear parameter within its effect's physical bounds (`lsq.Stats.coefs`
with `lower`, `search.Grid`): a value is chosen for what it explains with the effect's sign,
checked against scipy's bounded least squares."""

import numpy as np
from scipy.optimize import lsq_linear

from manus.adaptive.identify import lsq, search


def _problem(seed, rows=4000, P=5, bounded=2):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(rows, 1, P)) * rng.uniform(0.1, 10, P)  # columns of very different scales
    theta = rng.normal(size=P)
    theta[-bounded:] = [-0.8, 0.5][:bounded]  # one bounded parameter truly below its bound 0
    tau = X @ theta + 0.3 * rng.normal(size=(rows, 1))
    lower = np.r_[np.full(P - bounded, -np.inf), np.zeros(bounded)]
    return X, tau, lower


def test_bounded_coefficients_match_scipys_bounded_least_squares():
    for seed in range(5):
        X, tau, lower = _problem(seed)
        starts = np.arange(0, X.shape[0], 100)
        st = lsq.Stats.of(X, tau, starts)
        rng = np.random.default_rng(seed + 100)
        masks = rng.random((6, starts.size)) < 0.7
        C = st.coefs(masks, lower)
        for f, m in enumerate(masks):
            rows = np.repeat(m, 100)
            ref = lsq_linear(X[rows, 0], tau[rows, 0], bounds=(lower, np.inf), method="bvls", tol=1e-12).x
            np.testing.assert_allclose(st.theta(C[f]), ref, rtol=1e-7, atol=1e-9)
        free = st.coefs(masks)  # unbounded: the plain least squares, a parameter below 0
        assert np.all(free[:, -2] < 0) and np.all(C[:, -2] == 0)


def test_the_search_chooses_the_value_the_physics_allows():
    """Two values of a searched parameter: the first explains more of the torque with a negative
    coefficient (friction falling at low speed), the second less with a positive one. The search
    takes the second, and only it is free of its bound."""
    rng = np.random.default_rng(3)
    rows = 6000
    base = rng.normal(size=(rows, 1, 2))
    e1, e2 = rng.normal(size=(rows, 1, 1)), rng.normal(size=(rows, 1, 1))
    tau = base @ np.array([1.0, -0.5]) - 0.9 * e1[..., 0] + 0.3 * e2[..., 0] + 0.2 * rng.normal(size=(rows, 1))
    starts = np.arange(0, rows, 150)
    st0 = lsq.Stats.of(base, tau, starts)
    stats: list[search.Stats | None] = [st0.extend(e1), st0.extend(e2)]
    lower = np.array([-np.inf, -np.inf, 0.0])
    own = np.array([False, False, True])
    whole = np.ones(starts.size, bool)
    unbounded = search.Grid(["e1", "e2"], stats, None, None)
    bounded = search.Grid(["e1", "e2"], stats, None, None, lower, own)
    assert unbounded.choose(whole)[0] == 0
    assert bounded.choose(whole)[0] == 1
    assert bounded.free(whole).tolist() == [False, True]
    assert unbounded.free(whole).tolist() == [True, True]


def test_a_grid_of_values_at_once_matches_scipys_bounded_least_squares():
    """`Stats.extend` of V sets of columns at once (a grid's values, in chunks under a small
    budget) and its batched bounded fits and errors: each value's against scipy's bounded least
    squares on the same rows, and against the same value extended alone."""
    X, tau, lower = _problem(7, P=6, bounded=2)
    rng = np.random.default_rng(8)
    starts = np.arange(0, X.shape[0], 100)
    base = lsq.Stats.of(X[:, :, :4], tau, starts)
    E = np.stack(
        [
            X[:, :, 4:] * rng.uniform(0.5, 2.0, (1, 1, 2)) + 0.1 * v * rng.normal(size=X[:, :, 4:].shape)
            for v in range(5)
        ]
    )  # (V, rows, n, 2): five values of the searched columns
    every = base.extend(E, budget=3 * X.shape[0] * 6 * 2)  # (three values per chunk: two chunks)
    np.testing.assert_array_equal(base.extend(list(E), budget=3 * X.shape[0] * 6 * 2).G, every.G)  # (a list of them)
    masks = rng.random((4, starts.size)) < 0.7
    C = every.coefs(masks, lower)  # (V, F, P)
    errs = every.sses(C, masks)  # (V, F)
    for v in range(E.shape[0]):
        alone = base.extend(E[v])
        np.testing.assert_allclose(every.one(v).G, alone.G, rtol=1e-12)
        np.testing.assert_allclose(C[v], alone.coefs(masks, lower), rtol=1e-9, atol=1e-12)
        for f, m in enumerate(masks):
            rows = np.repeat(m, 100)
            Xv = np.concatenate([X[rows, 0, :4], E[v, rows, 0]], 1)
            fit = lsq_linear(Xv, tau[rows, 0], bounds=(lower, np.inf), method="bvls", tol=1e-12)
            np.testing.assert_allclose(every.one(v).theta(C[v, f]), fit.x, rtol=1e-7, atol=1e-9)
            np.testing.assert_allclose(errs[v, f], np.sum((Xv @ fit.x - tau[rows, 0]) ** 2), rtol=1e-8)
