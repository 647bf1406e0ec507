"""Physically consistent identification by default on a serial chain (manus.adaptive.identify.consistency
.physical, the last stage of `fit`): the Panda's torque from pinocchio's RNEA (an independent engine)
plus viscous and Coulomb friction and noise. Where the excitation is poor, least squares breaks
physics (an H(q) that is not positive definite on the recorded states, negative friction and
armatures): the fit returned is consistent (each link's pseudo-inertia PSD by numpy, armatures and
friction ≥ 0, H(q) positive definite), every rule the estimate breaks is listed, both errors are
reported, and the consistent error lies between least squares' (the minimum, against numpy's
lstsq) and the truth's (a consistent point). Where the motion excites the arm well, least squares
is consistent and the fit is least squares' bit for bit. IV's simulations start from the
consistent model; without the solver the estimate stands, said in one line."""

import dataclasses
import pathlib
import time

import jax
import numpy as np
import pytest

from manus.adaptive import Columns, fit
from manus.adaptive.identify import consistency
from manus.adaptive.identify.consistency import LINK, consistent, physical
from manus.adaptive.identify.instruments import iv_fit
from manus.adaptive.identify.result import fit_rows
from manus.plants import Serial
from manus.plants.errors import ManusError
from manus.plants.recording import Recording
from tests.adaptive.test_consistency import swung
from tests.plants.test_serial import load

MODEL = "rigid,viscous,coulomb"
B = np.array([0.3, 0.3, 0.25, 0.25, 0.15, 0.15, 0.1])  # viscous [N·m·s/rad]
FC = np.array([0.5, 0.5, 0.4, 0.4, 0.3, 0.3, 0.2])  # Coulomb [N·m]
CENTRE = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
DFKI = pathlib.Path(__file__).resolve().parents[2] / "examples" / "dfki_double_pendulum" / "double_pendulum_a0.urdf"


def panda(amplitude: float, seconds: float, noise: float, seed: int):
    """(recording, chain, truth by name): three sinusoids per joint of random frequencies (0.2-1 Hz)
    around `CENTRE`, `amplitude` [rad] in all, 500 Hz; the torque pinocchio's RNEA (armatures
    0.05-0.3 kg m²) plus friction (Coulomb smoothed over 1 mrad/s), with white noise of `noise`
    times each joint's torque RMS."""
    pin = pytest.importorskip("pinocchio")
    _, serial, model, data = load("panda")
    rng = np.random.default_rng(seed)
    t = np.arange(0, seconds, 2e-3)
    w, phase = 2 * np.pi * rng.uniform(0.2, 1.0, (7, 3)), rng.uniform(0, 2 * np.pi, (7, 3))
    a = amplitude * np.array([0.6, 0.3, 0.1])
    arg = w[None] * t[:, None, None] + phase
    q = CENTRE + np.einsum("k,tjk->tj", a, np.sin(arg))
    qd = np.einsum("k,jk,tjk->tj", a, w, np.cos(arg))
    qdd = -np.einsum("k,jk,tjk->tj", a, w**2, np.sin(arg))
    tau = np.stack([pin.rnea(model, data, *x) for x in zip(q, qd, qdd, strict=True)])  # pyright: ignore[reportAttributeAccessIssue]
    tau += B * qd + FC * np.tanh(qd / 1e-3)
    tau += noise * np.std(tau, 0) * rng.standard_normal(tau.shape)
    meta = {"sample_rate_hz": "500", "command_hold": "none", "structure": "urdf", "robot": serial.source}
    base = serial.base()
    truth = dict(zip(base.base_names, base.values(serial.defaults), strict=True))
    truth |= {f"b{i + 1}": v for i, v in enumerate(B)} | {f"Fc{i + 1}": v for i, v in enumerate(FC)}
    return Recording(t, q, tau, qd, meta), serial, truth


def lowest_eigenvalues(serial: Serial, base, params: dict, q: np.ndarray) -> np.ndarray:
    """The smallest eigenvalue of H(q) at each configuration, from base parameters (any standard
    set with these base parameters: `SerialBase.standard`)."""
    theta = base.standard(params)
    H = jax.vmap(lambda x: serial.mass_matrix(x, theta))(q)
    return np.linalg.eigvalsh(np.asarray(H))[:, 0]


def pseudo_inertia(p: np.ndarray) -> np.ndarray:
    """[[½ tr(I) 𝟙 − I, h], [hᵀ, m]] of one link's (m, mx, my, mz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz)."""
    I = np.array([[p[4], p[5], p[6]], [p[5], p[7], p[8]], [p[6], p[8], p[9]]])
    return np.block([[0.5 * np.trace(I) * np.eye(3) - I, p[1:4, None]], [p[None, 1:4], p[:1, None]]])


@pytest.fixture(scope="module")
def poor():
    """0.03 rad of motion for 3 s, 30 % noise: least squares breaks physics."""
    rec, serial, truth = panda(0.03, 3.0, 0.3, seed=3)
    return fit(rec, MODEL, method="ls"), serial, truth


def test_where_least_squares_breaks_physics_every_broken_rule_is_listed(poor):
    f, serial, _ = poor
    est = f.unconstrained
    assert est is not None, "least squares breaks physics here: the fit is moved"
    base = f.model.structure
    # the estimate is least squares' (numpy's lstsq on the same columns)
    Y = Columns(f.data).model(f.model)
    tau = f.data.tau(f.delay)
    theta = np.linalg.lstsq(Y.reshape(-1, Y.shape[2]), tau.reshape(-1), rcond=None)[0]
    np.testing.assert_allclose(est.theta, theta, rtol=1e-6, atol=1e-9 * np.abs(theta).max())
    # H(q) of its base parameters is indefinite on the recorded states; negative friction and armatures
    low = lowest_eigenvalues(serial, base, est.params, f.data.q[f.data.rows[::5]])
    negative = [k for k in (*base.armatures, *(f"b{i}" for i in range(1, 8)), *(f"Fc{i}" for i in range(1, 8)))]
    negative = [k for k in negative if est.params[k] < 0]
    print("LS: H's lowest eigenvalue", low.min(), "negative:", {k: round(est.params[k], 3) for k in negative})
    assert low.min() < 0 and any(k.startswith("Ia") for k in negative) and any(k.startswith("b") for k in negative)
    r = f.report()
    print("\n".join(r["violations"]))
    assert any("not positive definite" in v and "recorded states" in v for v in r["violations"])
    for k in negative:
        assert any(v.startswith(f"{k} = ") for v in r["violations"]), k
    assert f.violations() == r["violations"]


def test_the_fit_returned_is_consistent_and_both_errors_are_reported(poor):
    f, serial, truth = poor
    est = f.unconstrained
    assert est is not None
    base = f.model.structure
    cols = Columns(f.data)
    cols.model(f.model)
    start = time.perf_counter()
    c = consistent(est, cols)  # the stage again: the same parameters, with the standard ones that give them
    print(f"the stage, moving the estimate: {1e3 * (time.perf_counter() - start):.0f} ms ({f.data.rows.size} rows)")
    np.testing.assert_array_equal(c.theta, f.theta)
    n = serial.n_joints
    rigid = [f.names.index(k) for k in base.base_names]
    np.testing.assert_allclose(base.K @ c.standard, f.theta[rigid], atol=1e-7 * np.abs(f.theta[rigid]).max())
    for i in range(n):
        J = pseudo_inertia(c.standard[LINK * i : LINK * (i + 1)])
        assert np.linalg.eigvalsh(J)[0] >= -1e-8 * np.abs(J).max(), (i, np.linalg.eigvalsh(J))
    assert np.all(c.standard[LINK * n :] >= -1e-8)  # armatures
    assert all(f.params[k] >= -1e-8 for k in f.names if k.startswith(("b", "Fc")))
    assert all(f.params[k] >= -1e-8 for k in base.armatures)
    assert lowest_eigenvalues(serial, base, f.params, f.data.q[f.data.rows[::5]]).min() > 0
    assert not f.model.violations(f.params)  # its own parameters break no rule
    # both errors; least squares' is the smallest, the truth (consistent) leaves more than the closest consistent set
    Y = Columns(f.data).model(f.model)
    tau = f.data.tau(f.delay)
    rel = lambda theta: float(np.linalg.norm(tau - Y @ theta) / np.linalg.norm(tau))
    true = rel(np.array([truth[k] for k in f.names]))
    r = f.report()
    block = r["consistency"]
    print(f"rel_error: LS {est.rel_error:.5f}, consistent {f.rel_error:.5f}, truth {true:.5f}")
    assert block["moved"] and not block["already"]
    assert block["ls_rel_error"] == est.rel_error and block["rel_error"] == f.rel_error == r["rel_error"]
    assert f.rel_error == pytest.approx(rel(f.theta), rel=1e-9)
    assert est.rel_error <= f.rel_error <= true * 1.001
    assert set(block["moved_std"]) <= set(f.names)


def test_a_well_excited_arm_keeps_least_squares_bit_for_bit():
    rec, _, _ = panda(1.0, 4.0, 0.001, seed=0)
    f = fit(rec, MODEL, method="ls")
    cols = Columns(f.data)
    ls = fit_rows(f.data, cols, f.model)
    start = time.perf_counter()
    physical(ls, cols)
    print(f"the stage, the estimate consistent: {1e3 * (time.perf_counter() - start):.0f} ms ({f.data.rows.size} rows)")
    assert f.unconstrained is None and f.consistency is not None and f.consistency["already"]
    np.testing.assert_array_equal(f.theta, ls.theta)
    np.testing.assert_array_equal(f.residual, ls.residual)
    assert f.rel_error == ls.rel_error and not f.violations()
    r = f.report()
    assert r["consistency"]["ls_rel_error"] == r["consistency"]["rel_error"] == r["rel_error"]
    assert all(v == 0 for v in r["consistency"]["moved_std"].values())


@pytest.fixture(scope="module")
def dfki():
    """The DFKI double pendulum swung for 8 s (`tests.adaptive.test_consistency.swung`): least
    squares is consistent here."""
    return fit(swung(DFKI, 8.0), "rigid,viscous", method="ls")


def test_iv_simulates_from_the_consistent_model(dfki):
    """An estimate whose elbow inertia is negative cannot be simulated, so IV had nothing to start
    from; from its consistent parameters IV runs."""
    names = dfki.names
    theta = dfki.theta.copy()
    theta[names.index("Ia2")] = -0.05  # H(q) indefinite
    bad = dataclasses.replace(dfki, theta=theta, consistency=None)
    assert any("not positive definite" in v for v in bad.violations())
    cols = Columns(bad.data)
    assert "IV unavailable" in iv_fit(bad.data, cols, bad, "iv").why
    start = physical(bad, cols)
    assert start.unconstrained is bad and not start.model.violations(start.params)
    iv = iv_fit(bad.data, cols, bad, "iv", start)
    assert iv.method == "iv" and iv.rel_error < 2 * dfki.rel_error


def test_without_the_solver_the_estimate_stands_said_in_one_line(dfki, monkeypatch):
    def missing(module, extra):
        raise ManusError(f"this needs {module}, which is not installed: pip install 'manus[{extra}]'")

    monkeypatch.setattr(consistency, "require", missing)
    theta = dfki.theta.copy()
    theta[dfki.names.index("b2")] = -0.05
    bad = dataclasses.replace(dfki, theta=theta, consistency=None)
    f = physical(bad)
    assert f is not bad and np.array_equal(f.theta, bad.theta) and f.unconstrained is None
    line = f.report()["consistency"]["error"]
    assert "\n" not in line and "manus[consistency]" in line and "estimate kept" in line
    assert any(v.startswith("b2 = ") for v in f.violations())


def test_other_structures_keep_their_estimate_and_list_what_it_breaks():
    """MANUS-2 (not a chain): no consistent stage, the estimate is the fit; `violations` names an
    H(q) that is not positive definite and each friction coefficient below its bound."""
    from tests.adaptive import hidden

    f = fit(hidden.recording(()), MODEL, method="ls")
    assert f.consistency is None and "consistency" not in f.report() and not f.violations()
    theta = f.theta.copy()
    theta[f.names.index("a1")] = -abs(theta[f.names.index("a1")])  # H(q) indefinite
    theta[f.names.index("b2")] = -1.0
    theta[f.names.index("Fc1")] = -1.0
    bad = dataclasses.replace(f, theta=theta)
    assert physical(bad) is bad
    out = bad.violations()
    print("\n".join(out))
    assert any("not positive definite" in v for v in out)
    assert any(v.startswith("b2 = ") for v in out) and any(v.startswith("Fc1 = ") for v in out)
