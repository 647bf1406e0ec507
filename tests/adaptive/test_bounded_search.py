"""The search of a non-linear parameter within its effect's physical bounds (`lsq.Stats.coefs`
with `lower`, `search.Grid`): a value is chosen for what it explains with the effect's sign,
checked against scipy's bounded least squares."""

import numpy as np
from scipy.optimize import lsq_linear

from manus.adaptive import lsq, search


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
        st = lsq.Stats(X, tau, starts)
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
    st0 = lsq.Stats(base, tau, starts)
    stats = [st0.extend(e1), st0.extend(e2)]
    lower = np.array([-np.inf, -np.inf, 0.0])
    own = np.array([False, False, True])
    whole = np.ones(starts.size, bool)
    unbounded = search.Grid(["e1", "e2"], stats, None, None)
    bounded = search.Grid(["e1", "e2"], stats, None, None, lower, own)
    assert unbounded.choose(whole)[0] == 0
    assert bounded.choose(whole)[0] == 1
    assert bounded.free(whole).tolist() == [False, True]
    assert unbounded.free(whole).tolist() == [True, True]
