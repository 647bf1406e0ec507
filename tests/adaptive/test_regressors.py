"""Regressors against hand-written equations, the model's own torque, and the Slotine–Li
skew-symmetry property (Ḣ by automatic differentiation along a trajectory)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.adaptive.regressors import Regressor
from manus.plants.effects import Model
from manus.plants.errors import ModelError
from manus.plants.references import Complex
from manus.plants.structures import Axis, Manus2

ALL_LINEAR = "rigid,viscous,coulomb,stribeck,asymmetry,offset,gravity,cogging"


def test_hdot_minus_2c_is_skew_symmetric_along_a_trajectory():
    s, p = Manus2(), dict(zip(("a1", "a2", "a3"), (0.349, 0.241, 0.246), strict=True))
    ref = Complex()
    rng = np.random.default_rng(0)
    largest = 0.0
    for t in np.linspace(0.05, 1.0, 20):
        q, qd = ref(t).q, ref(t).qd
        H_dot = jax.jacfwd(lambda t: s.inertia(ref(t).q, p))(jnp.asarray(t))  # dH(q(t))/dt
        N = np.asarray(H_dot - 2 * s.coriolis(q, qd, p))
        np.testing.assert_allclose(N + N.T, 0, atol=1e-13)
        x = rng.normal(size=2)
        assert abs(x @ N @ x) < 1e-13
        largest = max(largest, np.abs(N).max())
    assert largest > 1e-3  # not trivially zero (it is where the relative angle stands still)


def thesis_equations(q, qd, qd_r, qdd_r, a, form, b=(0, 0), fc=(0, 0), phi=0.01):
    """Eqs. C.1–C.2 / 3.2–3.3 by hand along the reference, friction at q̇_r."""
    c, s = np.cos(q[1] - q[0]), np.sin(q[1] - q[0])
    v1, v2 = qd if form == "slotine-li" else qd_r  # the Coriolis slot that is not q̇_r
    sat = np.clip(np.asarray(qd_r) / phi, -1, 1)
    return np.array(
        [
            a[0] * qdd_r[0] + a[1] * (c * qdd_r[1] - s * v2 * qd_r[1]) + b[0] * qd_r[0] + fc[0] * sat[0],
            a[1] * (c * qdd_r[0] + s * v1 * qd_r[0]) + a[2] * qdd_r[1] + b[1] * qd_r[1] + fc[1] * sat[1],
        ]
    )


@pytest.mark.parametrize("form", ["slotine-li", "thesis"])
def test_manus2_regressor_matches_the_hand_written_equations(form):
    model = Model(Manus2(), "rigid,viscous,coulomb")
    reg = Regressor(model, form, boundary=0.01)
    rng = np.random.default_rng(1)
    for _ in range(10):
        q, qd, qd_r = rng.uniform(-3, 3, 2), rng.normal(0, 1, 2), rng.normal(0, 0.02, 2)
        qdd_r = rng.normal(0, 5, 2)
        theta = rng.uniform(0.05, 0.5, 7)
        expected = thesis_equations(q, qd, qd_r, qdd_r, theta[:3], form, theta[3:5], theta[5:])
        np.testing.assert_allclose(reg(q, qd, qd_r, qdd_r) @ theta, expected, rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(reg.torque(q, qd, qd_r, qdd_r, theta), expected, rtol=1e-12, atol=1e-14)


def test_slotine_li_form_uses_the_measured_velocity_and_the_thesis_form_does_not():
    reg, thesis = Regressor(Model(Manus2(), "rigid")), Regressor(Model(Manus2(), "rigid"), "thesis")
    q, qd_r, qdd_r = np.array([0.4, 2.4]), np.array([0.3, -0.5]), np.array([1.0, 2.0])
    a, b = reg(q, np.array([1.0, 1.0]), qd_r, qdd_r), reg(q, np.array([2.0, -1.0]), qd_r, qdd_r)
    assert np.abs(a - b).max() > 0.1
    np.testing.assert_array_equal(
        thesis(q, np.array([1.0, 1.0]), qd_r, qdd_r), thesis(q, np.array([2.0, -1.0]), qd_r, qdd_r)
    )


@pytest.mark.parametrize("structure", [Manus2(), Axis(n_joints=3)], ids=["manus2", "axis3"])
@pytest.mark.parametrize("form", ["slotine-li", "thesis"])
def test_along_the_true_motion_y_theta_is_the_model_torque(structure, form):
    """With q̇_r = q̇ and q̈_r = q̈ both forms are the inverse dynamics `Model.torque`."""
    model = Model(structure, ALL_LINEAR)
    reg = Regressor(model, form, boundary=0.02)
    rng = np.random.default_rng(2)
    n = structure.n_joints
    for _ in range(5):
        q, qd, qdd = rng.uniform(-3, 3, n), rng.normal(0, 1, n), rng.normal(0, 5, n)
        theta = rng.normal(0, 1, len(model.names))
        expected = model.torque(q, qd, qdd, model.unvector(jnp.asarray(theta)), boundary=0.02)
        np.testing.assert_allclose(reg(q, qd, qd, qdd) @ theta, expected, rtol=1e-12, atol=1e-12)


def test_models_an_adaptive_controller_cannot_use_are_refused():
    with pytest.raises(ModelError, match="no 'rigid' effect"):
        Regressor(Model(Manus2(), "viscous"))
    with pytest.raises(ModelError, match="not linear in parameters"):
        Regressor(Model(Manus2(), "rigid,viscous,delay"))
    with pytest.raises(ModelError, match="unknown regressor form"):
        Regressor(Model(Manus2(), "rigid"), "textbook")


@pytest.mark.parametrize("form", ["slotine-li", "thesis"])
def test_a_stated_transmission_reaches_the_adaptive_regressor(form):
    """With the elbow's motor on q2 − q1 (θ = N q), the adaptation's friction columns are the
    model's own: the motor-side effects evaluated at N q̇_r and mapped by Nᵀ (along q̇ = q̇_r,
    either form's regressor is the inverse-dynamics one)."""
    from manus.plants.transmission import stated, with_transmission

    s = stated(Manus2(), "q1; q2 - q1")
    model = Model(s, "rigid,viscous,coulomb,offset")
    reg = Regressor(model, form=form, boundary=0.01)
    q, qd, qdd = jnp.array([0.4, 2.3]), jnp.array([0.3, 0.5]), jnp.array([-1.0, 2.0])
    Y = np.asarray(reg(q, qd, qd, qdd))
    np.testing.assert_allclose(Y, np.asarray(model.regressor(q, qd, qdd, boundary=0.01)), atol=1e-12)
    # the viscous columns by hand: Nᵀ diag(N q̇)
    N = np.array([[1.0, 0.0], [-1.0, 1.0]])
    b = [model.names.index(k) for k in ("b1", "b2")]
    np.testing.assert_allclose(Y[:, b], N.T @ np.diag(N @ np.asarray(qd)), atol=1e-12)
    plain = np.asarray(
        Regressor(Model(with_transmission(s, None), model.effects), form=form, boundary=0.01)(q, qd, qd, qdd)
    )
    assert not np.allclose(plain[:, b], Y[:, b])
