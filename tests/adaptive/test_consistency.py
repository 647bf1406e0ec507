"""The physically consistent stage of a serial chain's fit (manus.adaptive.identify.consistency): the
pseudo-inertia against pinocchio's, and the convex (LMI) solution against an independent one, a
log-Cholesky parametrization (Rucker and Wensing 2022: J = U Uᵀ is positive semidefinite for any
U) minimized by scipy."""

import dataclasses
import pathlib

import numpy as np
import pinocchio as pin
import pytest
from scipy import linalg, optimize

from manus.adaptive import Columns, fit
from manus.adaptive.identify.consistency import LINK, TIE, WEAK, consistent, pseudo_inertia
from manus.plants import Serial
from manus.plants.recording import Recording

URDF = pathlib.Path(__file__).resolve().parents[2] / "examples" / "dfki_double_pendulum" / "double_pendulum_a0.urdf"
OURS_TO_PIN = [0, 1, 2, 3, 4, 5, 7, 6, 8, 9]  # pinocchio: Ixx, Ixy, Iyy, Ixz, Iyz, Izz; ours: Ixx, Ixy, Ixz, Iyy, ...


def test_pseudo_inertia_is_pinocchios():
    rng = np.random.default_rng(3)
    for _ in range(5):
        m, c = rng.uniform(0.5, 3), rng.normal(size=3) * 0.2
        a, b, h = rng.uniform(0.05, 0.5, 3)  # a box, turned at random: a real body
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        rotational = R @ np.diag(m / 12 * np.array([b**2 + h**2, a**2 + h**2, a**2 + b**2])) @ R.T
        inertia = pin.Inertia(m, c, rotational)  # pyright: ignore[reportAttributeAccessIssue]  (compiled, no stubs)
        p_pin = inertia.toDynamicParameters()
        ours = np.empty(10)
        ours[OURS_TO_PIN] = p_pin
        np.testing.assert_allclose(
            pseudo_inertia(ours),
            pin.PseudoInertia.FromDynamicParameters(p_pin).toMatrix(),  # pyright: ignore[reportAttributeAccessIssue]
            atol=1e-12,
        )
        assert np.linalg.eigvalsh(pseudo_inertia(ours))[0] > 0


def swung(path, seconds: float) -> Recording:
    """The chain of the URDF at `path` (two joints) driven along a smooth motion for `seconds`, its
    torque from our RNEA plus viscous friction and noise (1 % of the RMS): a consistent truth, the
    URDF's."""
    import jax

    serial = Serial.from_urdf(path)
    t = np.arange(0, seconds, 2e-3)
    w = 2 * np.pi * np.array([[0.31, 0.73, 1.3], [0.43, 0.97, 1.7]])
    a = np.array([[0.9, 0.3, 0.1], [0.8, 0.4, 0.15]])
    arg = w[None] * t[:, None, None] + 0.3
    q = np.einsum("jk,tjk->tj", a, np.sin(arg))
    qd = np.einsum("jk,tjk->tj", a * w, np.cos(arg))
    qdd = np.einsum("jk,tjk->tj", -a * w**2, np.sin(arg))
    rnea = jax.jit(jax.vmap(lambda q1, qd1, qdd1: serial.rnea(q1, qd1, qdd1, serial.defaults)))
    tau = np.asarray(rnea(q, qd, qdd)) + 0.02 * qd
    tau += 0.01 * np.std(tau, 0) * np.random.default_rng(0).normal(size=tau.shape)
    meta = {"sample_rate_hz": "500", "command_hold": "none", "structure": "urdf", "robot": str(path)}
    return Recording(t, q, tau, qd, meta)


@pytest.fixture(scope="module")
def swing():
    """The DFKI chain swung for 10 s (`swung`), fitted by least squares."""
    return fit(swung(URDF, 10.0), "rigid,viscous", method="ls")


def test_a_consistent_estimate_stays(swing):
    """The truth is consistent: so is the estimate; the stage moves nothing by more than a tenth of
    a standard deviation, and its masses are the URDF's (the data do not hold them)."""
    c = consistent(swing)
    r = c.report()
    assert r["already"] and r["status"] == "optimal"
    assert max(abs(v) for v in r["moved_std"].values()) < 0.1, r["moved_std"]
    assert r["rel_error"] == pytest.approx(swing.rel_error, rel=1e-3)
    assert [x["mass"] for x in r["links"]] == pytest.approx([0.5594, 0.6043], rel=0.2)
    base = swing.model.structure
    np.testing.assert_allclose(base.K @ c.standard, c.theta[[swing.names.index(k) for k in base.base_names]], atol=1e-8)


def _objective(f):
    """The stage's objective, written out independently: the rise of the squared torque error in
    units of the residual variance per row, plus TIE times the squared relative distance of the
    standard parameters from the URDF's on the combinations no base parameter holds (scipy's
    null space of K in relative units), WEAK times it on every standard parameter."""
    Y = Columns(f.data).model(f.model)
    Y = Y.reshape(-1, Y.shape[2])
    var = float(np.sum(f.residual**2)) / (Y.shape[0] - Y.shape[1])
    prior = np.asarray(f.model.structure.serial.defaults)
    G = Y.T @ Y / var
    D = np.maximum(np.abs(prior), 1e-3)
    null = linalg.null_space(f.model.structure.K * D)

    def value(x, phi):
        d, u = x - f.theta, (phi - prior) / D
        return d @ G @ d + TIE * (np.sum((null.T @ u) ** 2) + WEAK * np.sum(u**2))

    return value


def test_an_inconsistent_estimate_against_log_cholesky(swing):
    """A negative inertia about the elbow and a negative viscous coefficient, which no bodies
    give: the LMI solution is consistent (every pseudo-inertia's eigenvalues ≥ 0, b ≥ 0, armatures
    ≥ 0) and as good as the log-Cholesky optimum found by scipy from the URDF (a convex problem:
    no better point exists)."""
    names = swing.names
    theta = swing.theta.copy()
    theta[names.index("Iyy2")] = -0.01
    theta[names.index("b2")] = -0.05
    f = dataclasses.replace(swing, theta=theta)
    c = consistent(f)
    r = c.report()
    assert not r["already"]
    n = 2
    for i in range(n):
        J = pseudo_inertia(c.standard[LINK * i : LINK * (i + 1)])
        assert np.linalg.eigvalsh(J)[0] > -1e-9 * np.abs(J).max()
    assert np.all(c.standard[LINK * n :] > -1e-8) and c.theta[names.index("b2")] > -1e-8  # to the solver's tolerance

    base = f.model.structure
    rigid = [names.index(k) for k in base.base_names]
    others = [j for j in range(len(names)) if j not in rigid]
    bounded = [j for j in others if names[j].startswith("b")]
    tri = np.triu_indices(4)

    def unpack(z):
        phi = []
        for i in range(n):
            U = np.zeros((4, 4))
            U[tri] = z[10 * i : 10 * (i + 1)]
            J = U @ U.T
            Sigma, h, m = J[:3, :3], J[:3, 3], J[3, 3]
            inertia = np.trace(Sigma) * np.eye(3) - Sigma
            phi += [m, *h, inertia[0, 0], inertia[0, 1], inertia[0, 2], inertia[1, 1], inertia[1, 2], inertia[2, 2]]
        phi += list(z[10 * n : 11 * n] ** 2)  # armatures
        phi = np.array(phi)
        x = np.empty(len(names))
        x[rigid] = base.K @ phi
        rest = z[11 * n :]
        x[others] = [rest[k] ** 2 if j in bounded else rest[k] for k, j in enumerate(others)]
        return x, phi

    prior = np.asarray(base.serial.defaults)
    z0 = []
    for i in range(n):
        J = np.asarray(pseudo_inertia(prior[LINK * i : LINK * (i + 1)]))
        U = np.linalg.cholesky(J[::-1, ::-1])[::-1, ::-1]  # J = U Uᵀ
        z0 += list(U[tri])
    z0 += list(np.sqrt(prior[LINK * n :]))
    z0 += [np.sqrt(max(theta[j], 0)) if j in bounded else theta[j] for j in others]
    objective = _objective(f)
    best = optimize.minimize(
        lambda z: objective(*unpack(z)), np.array(z0), method="BFGS", options={"gtol": 1e-10, "maxiter": 20000}
    )
    ours = objective(c.theta, c.standard)
    assert ours <= best.fun * (1 + 1e-4) + 1e-9, (ours, best.fun)
    assert ours >= best.fun * (1 - 1e-3), (ours, best.fun)  # scipy reaches the same optimum
