"""Parameter projection: against a brute-force weighted projection (scipy), admissibility, and
the property the Lyapunov proof needs (never farther from any admissible truth in Γ⁻¹)."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
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
        r = minimize(lambda x: np.sum((x - y) ** 2 / g), x0, method="SLSQP", tol=1e-14,
                     constraints=[{"type": "ineq", "fun": lambda x: x[0] * x[2] - x[1] ** 2},
                                  {"type": "ineq", "fun": lambda x: x[0]}, {"type": "ineq", "fun": lambda x: x[2]}])
        if best is None or r.fun < best.fun:
            best = r
    return best.x


def test_cone_projection_matches_a_brute_force_weighted_projection():
    rng = np.random.default_rng(0)
    psd = eqx.filter_jit(project_psd2)
    for _ in range(25):
        y, g = rng.normal(0, 0.3, 3), rng.uniform(0.1, 1.0, 3)
        got = np.array(psd(*y, *g))
        ref = brute_force(y, g)
        np.testing.assert_allclose(got, ref, atol=2e-6)


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
