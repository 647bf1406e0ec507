"""Parameter projection: against the exact search it replaced (a grid plus golden section over the
boundary's rank-one rays) and a brute-force weighted projection (scipy), on random points near,
far outside and on the boundary of the cone; admissibility, and the property the Lyapunov proof
needs (never farther from any admissible truth in Γ⁻¹)."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import minimize

from manus.adaptive.projection import Projection, project_psd2
from manus.plants.effects import Model
from manus.plants.structures import Axis, Manus2

MODEL = Model(Manus2(), "rigid,viscous,coulomb,offset")
GAMMA = np.array([0.2, 0.2, 0.5, 20, 20, 20, 20, 20, 20])
EPS = 1e-3
project = eqx.filter_jit(Projection(MODEL, EPS))


def brute_force(y, g):
    """min Σ (x − y)²/g over {[[u, v], [v, w]] ⪰ 0} with SLSQP, from several starts."""
    best = None
    for x0 in ([1.0, 0.0, 1.0], [abs(y[0]) + 0.1, 0.0, abs(y[2]) + 0.1], [0.1, 0.05, 0.1]):
        r = minimize(
            lambda x: np.sum((x - y) ** 2 / g),
            x0,
            method="SLSQP",
            tol=1e-14,
            constraints=[
                {"type": "ineq", "fun": lambda x: x[0] * x[2] - x[1] ** 2},
                {"type": "ineq", "fun": lambda x: x[0]},
                {"type": "ineq", "fun": lambda x: x[2]},
            ],
        )
        if best is None or r.fun < best.fun:
            best = r
    return best.x


def exact_search(u, v, w, g1, g2, g3, grid=32, golden_steps=40):
    """The projection the controller used before (a reference here): a point outside the cone
    lands on its boundary, the rank-one matrices t n nᵀ, n = (cos φ, sin φ), t ≥ 0; for each φ the
    best t is closed-form, and φ comes from a grid over [0, π) refined by golden section (to
    about 1e-9 rad)."""
    inv_phi = (math.sqrt(5) - 1) / 2

    def ray(phi):
        c, s = jnp.cos(phi), jnp.sin(phi)
        return c * c, c * s, s * s

    def fit(phi):
        r = ray(phi)
        num = u * r[0] / g1 + v * r[1] / g2 + w * r[2] / g3
        den = r[0] ** 2 / g1 + r[1] ** 2 / g2 + r[2] ** 2 / g3
        return jnp.maximum(num, 0.0) ** 2 / den, jnp.maximum(num, 0.0) / den  # gain, best t

    phis = jnp.arange(grid) * (jnp.pi / grid)
    best = phis[jnp.argmax(jax.vmap(lambda p: fit(p)[0])(phis))]
    h = jnp.pi / grid

    def golden(_, ab):
        a, b = ab
        c, d = b - inv_phi * (b - a), a + inv_phi * (b - a)
        left = fit(c)[0] >= fit(d)[0]
        return jnp.where(left, a, c), jnp.where(left, d, b)

    a, b = jax.lax.fori_loop(0, golden_steps, golden, (best - h, best + h))
    phi = 0.5 * (a + b)
    t = fit(phi)[1]
    r = ray(phi)
    inside = (u >= 0) & (w >= 0) & (u * w >= v * v)
    return tuple(jnp.where(inside, x, t * ri) for x, ri in zip((u, v, w), r, strict=True))


def random_cases(rng, n):
    """Points (n, 3) and gains (n, 3): near the cone, far outside it (every direction, up to 1e3),
    on its boundary (rank-one matrices) and just off it either side, with gain ratios up to 1e3."""
    g = np.exp(rng.uniform(np.log(1e-3), 0.0, (n, 3)))
    y = rng.normal(0, 0.3, (n, 3))
    far = rng.normal(0, 1, (n, 3)) * 10.0 ** rng.uniform(1, 3, (n, 1))
    phi, t = rng.uniform(0, np.pi, n), rng.uniform(0.01, 2, n)
    ray = np.stack([np.cos(phi) ** 2, np.cos(phi) * np.sin(phi), np.sin(phi) ** 2], 1) * t[:, None]
    off = ray + rng.normal(0, 1e-6, (n, 3))
    k = n // 4
    return np.concatenate([y[:k], far[:k], ray[:k], off[: n - 3 * k]]), g


def test_cone_projection_matches_the_exact_search_it_replaced():
    rng = np.random.default_rng(0)
    y, g = random_cases(rng, 4000)
    new = np.array(jax.jit(jax.vmap(project_psd2))(*y.T, *g.T)).T
    old = np.array(jax.jit(jax.vmap(exact_search))(*y.T, *g.T)).T
    d = lambda x: np.sum((x - y) ** 2 / g, axis=1)
    # never farther than the search's point (the distance in the metric, to rounding) ...
    assert np.all(d(new) <= d(old) * (1 + 1e-12))
    # ... and the same point, to the search's precision (the distance is flat along the boundary:
    # a search that finds the distance to rounding finds the point only to about 1e-7), except
    # where the search missed: a few points far out with gain ratios near 1e3, where the grid
    # steps over the narrow range of rays it should refine and the search returns 0 (or a worse
    # point; checked here against the distance)
    missed = d(old) - d(new) > 1e-9 * np.sum(y * y / g, axis=1)
    assert missed.sum() < 0.005 * len(y)
    scale = np.linalg.norm(y, axis=1, keepdims=True)
    np.testing.assert_allclose(new[~missed] / scale[~missed], old[~missed] / scale[~missed], atol=3e-7)


def test_cone_projection_matches_a_brute_force_weighted_projection():
    rng = np.random.default_rng(0)
    psd = jax.jit(project_psd2)
    for _ in range(25):
        y, g = rng.normal(0, 0.3, 3), rng.uniform(0.1, 1.0, 3)
        got = np.array(psd(*y, *g))
        ref = brute_force(y, g)
        np.testing.assert_allclose(got, ref, atol=2e-6)


def test_cone_projection_is_the_projection_onto_the_boundary_and_admissible():
    """The optimality condition of a projection onto a convex set, in the metric diag(1/g):
    ⟨y − x, k − x⟩ ≤ 0 for every k in the cone (here many random k), and x in the cone."""
    rng = np.random.default_rng(3)
    y, g = random_cases(rng, 400)
    x = np.array(jax.jit(jax.vmap(project_psd2))(*y.T, *g.T)).T
    scale = np.sum(y * y / g, axis=1)
    assert np.all(x[:, 0] * x[:, 2] - x[:, 1] ** 2 >= -1e-12 * scale * g.max(1) ** 2)
    assert np.all(x[:, 0] >= -1e-12 * np.abs(y).max(1)) and np.all(x[:, 2] >= -1e-12 * np.abs(y).max(1))
    for _ in range(20):
        a, b = rng.normal(0, 1, (2, len(y))) * np.abs(y).max(1) * 2
        k = np.stack([a * a, a * b, b * b], 1)  # rank one: the boundary, where a violation would show
        assert np.all(np.sum((y - x) * (k - x) / g, axis=1) <= 1e-9 * scale)


def test_cone_projection_of_a_negative_definite_point_is_zero_and_of_an_inside_point_itself():
    g = jnp.array([0.2, 0.2, 0.5])
    np.testing.assert_array_equal(project_psd2(-1.0, 0.1, -2.0, *g), (0.0, 0.0, 0.0))
    np.testing.assert_array_equal(project_psd2(0.3, 0.2, 0.4, *g), (0.3, 0.2, 0.4))
    np.testing.assert_allclose(project_psd2(1.0, 0.0, -2.0, *g), (1.0, 0.0, 0.0), atol=1e-15)


def test_the_projection_vectorizes_and_branches_once_per_batch():
    """The cone projection is elementwise arithmetic (no while loop or LAPACK call); under vmap
    its one conditional branches on the whole batch (a scalar predicate: any trial outside), and
    the batch comes out as each point projected alone (to rounding: vector and scalar code), whether
    some, none or all are outside; inside points bit for bit."""
    proj = Projection(MODEL, EPS)
    batched = jax.jit(jax.vmap(lambda t, g: proj(t, g)))
    hlo = batched.lower(jnp.zeros((8, 9)), jnp.ones((8, 9))).as_text()
    for op in ("while", "custom_call"):
        assert f"stablehlo.{op}" not in hlo and f" {op}(" not in hlo, op
    assert hlo.count("stablehlo.case") + hlo.count("stablehlo.if") == 1
    rng = np.random.default_rng(4)
    inside = np.tile([0.349, 0.241, 0.246, 0.22, 0.18, 0.1, 0.14, -0.05, 0.03], (8, 1))
    outside = rng.normal(0, 0.3, (8, 9))
    gains = np.exp(rng.uniform(-3, 0, (8, 9)))
    for thetas in (inside, outside, np.concatenate([inside[:7], outside[:1]])):
        got = np.asarray(batched(jnp.asarray(thetas), jnp.asarray(gains)))
        alone = np.array(
            [np.asarray(project(jnp.asarray(t), jnp.asarray(g))) for t, g in zip(thetas, gains, strict=True)]
        )
        np.testing.assert_allclose(got, alone, rtol=1e-14, atol=1e-16)
    np.testing.assert_array_equal(np.asarray(batched(jnp.asarray(inside), jnp.asarray(gains))), inside)


def test_admissible_estimates_are_left_alone():
    theta = jnp.array([0.349, 0.241, 0.246, 0.22, 0.18, 0.1, 0.14, -0.05, 0.03])
    np.testing.assert_array_equal(project(theta, GAMMA), theta)


def test_projection_keeps_h_positive_definite_and_friction_non_negative():
    rng = np.random.default_rng(1)
    angles = np.linspace(-np.pi, np.pi, 73)
    for _ in range(40):
        theta = rng.normal(0, 0.3, 9)
        x = np.asarray(project(jnp.asarray(theta), GAMMA))
        a1, a2, a3 = x[:3]
        for c in np.cos(angles):
            assert np.linalg.eigvalsh([[a1, a2 * c], [a2 * c, a3]])[0] >= EPS - 1e-9
        assert np.all(x[3:7] >= 0)
        np.testing.assert_array_equal(x[7:], theta[7:])  # offsets are signed: untouched


def test_projection_never_moves_away_from_an_admissible_truth_in_the_gamma_metric():
    rng = np.random.default_rng(2)
    for _ in range(40):
        y = rng.normal(0, 0.3, 9)
        truth = np.asarray(project(jnp.asarray(rng.normal(0, 0.3, 9)), GAMMA))  # any admissible point
        x = np.asarray(project(jnp.asarray(y), GAMMA))
        assert np.sum((x - truth) ** 2 / GAMMA) <= np.sum((y - truth) ** 2 / GAMMA) + 1e-10


def test_single_axes_keep_a_positive_mass():
    p = Projection(Model(Axis(n_joints=2), "rigid,coulomb"), min_inertia=0.01)
    np.testing.assert_allclose(p(jnp.array([-1.0, 2.0, -0.3, 0.4]), jnp.ones(4)), [0.01, 2.0, 0.0, 0.4])
