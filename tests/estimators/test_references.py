"""Every estimator three ways: `lax.scan` over the array (`run`), its jitted step in a Python
loop, and an independent reference (numpy, scipy, filterpy), agreeing to 1e-9."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize
import scipy.signal
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import ExtendedKalmanFilter, KalmanFilter

from manus import estimators
from manus.estimators.kalman import KinematicKalman, transition
from manus.estimators.luenberger import Luenberger
from manus.estimators.model_kalman import ModelKalman
from manus.estimators.sliding import K1, K2
from tests.estimators.conftest import DT, STEP

R = STEP**2 / 12
A1, A2, A3, B, FC, PHI = 0.349, 0.241, 0.246, (0.222, 0.181), (0.099, 0.139), 0.01  # thesis nominal model


scan = eqx.filter_jit(estimators.run)


def scan_and_loop(est, q, tau):
    """(scan, loop) velocity estimates (T, n); the loop feeds the torque of the previous sample."""
    scanned = np.asarray(scan(est, jnp.asarray(q), jnp.asarray(tau)).qd)
    step = estimators.compiled_step(est)
    state, looped, prev = est.init(jnp.asarray(q[0])), [], np.zeros(q.shape[1])
    for k in range(len(q)):
        state, out = step(state, jnp.asarray(q[k]), jnp.asarray(prev))
        looped.append(np.asarray(out.qd))
        prev = tau[k]
    return scanned, np.array(looped)


def agree(est, q, tau, reference):
    scanned, looped = scan_and_loop(est, q, tau)
    scale = np.abs(reference).max()
    assert scale > 0.1  # a real motion, not zeros
    np.testing.assert_allclose(scanned, reference, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(looped, reference, rtol=0, atol=1e-9 * scale)


def test_first_difference(motion):
    q, tau = motion
    agree(estimators.make("first_difference"), q, tau, np.vstack([np.zeros(2), np.diff(q, axis=0) / DT]))


def test_filtered_first_difference_is_the_tustin_transform_of_eq_3_19(motion):
    q, tau = motion
    b, a = scipy.signal.bilinear([188.5, 0.0], [1.0, 188.5], fs=1 / DT)  # λs/(s + λ)
    # at rest at q[0] before the first sample: past input q[0], past output 0
    ref = np.stack(
        [scipy.signal.lfilter(b, a, q[:, j], zi=scipy.signal.lfiltic(b, a, [0.0], [q[0, j]]))[0] for j in range(2)], 1
    )
    agree(estimators.make("filtered_first_difference"), q, tau, ref)


@pytest.mark.parametrize("name, order", [("kalman_cv", 2), ("kalman_ca", 3)])
@pytest.mark.parametrize("steady", [False, True])
def test_kinematic_kalman_equals_filterpy(motion, name, order, steady):
    q, tau = motion
    est = estimators.make(name, steady=steady)
    assert isinstance(est, KinematicKalman)
    refs = []
    for j in range(2):
        kf = KalmanFilter(dim_x=order, dim_z=1)
        kf.F, kf.H, kf.R = transition(order, DT), np.eye(1, order), np.array([[R]])
        kf.Q = Q_continuous_white_noise(order, DT, float(est.q))  # pyright: ignore[reportAttributeAccessIssue]
        kf.x = np.zeros((order, 1))
        kf.x[0, 0] = q[0, j]
        kf.P = np.array(est.P0)
        v = []
        for y in q[:, j]:
            kf.predict()
            kf.update(y)
            v.append(kf.x[1, 0])
        refs.append(v)
        # the starting covariance is filterpy's own fixed point: the steady state
        np.testing.assert_allclose(kf.P, est.P0, rtol=1e-6, atol=0)
    agree(est, q, tau, np.array(refs).T)


@pytest.mark.parametrize("order", [2, 3])
@pytest.mark.parametrize("steady", [False, True])
def test_kinematic_kalman_equals_a_numpy_matrix_kalman_from_random_states(order, steady):
    """The per-joint scalar step against the textbook matrix form (predict F x, F P Fᵀ + Q;
    gain P̄Hᵀ/S; Joseph update), from random estimates and covariances (far from the steady
    state), random noise densities and random (not quantized) measurements, 3 joints."""
    from manus.estimators.kalman import KalmanState, KinematicKalman, white_noise_covariance

    rng = np.random.default_rng(order)
    n, T = 3, 200
    q_density = 10.0 ** rng.uniform(-2, 4)
    est = KinematicKalman(DT, order, q=q_density, steady=steady)
    F, Q, H, r = transition(order, DT), q_density * white_noise_covariance(order, DT), np.eye(1, order), R
    scale = DT ** -np.arange(order)  # position, velocity, acceleration of comparable size per tick
    x = rng.normal(size=(n, order)) * 1e-3 * scale
    A = rng.normal(size=(n, order, order)) * 1e-4 * scale[:, None]
    P = A @ np.swapaxes(A, 1, 2) + 1e-12 * np.eye(order)  # symmetric positive definite
    ys = 1e-3 * np.cumsum(rng.normal(size=(T, n)), axis=0)
    step = estimators.compiled_step(est)
    state = KalmanState(jnp.asarray(x), None if steady else jnp.asarray(P))
    for y in ys:
        state, out = step(state, jnp.asarray(y), jnp.zeros(n))
        for j in range(n):
            x[j] = F @ x[j]
            if steady:
                K = np.asarray(est.K)
            else:
                Pb = F @ P[j] @ F.T + Q
                K = (Pb @ H.T / (H @ Pb @ H.T + r))[:, 0]
                IKH = np.eye(order) - np.outer(K, H)
                P[j] = IKH @ Pb @ IKH.T + r * np.outer(K, K)
            x[j] = x[j] + K * (y[j] - x[j, 0])
        xs, Ps = state
        close(xs, x, axis=0)  # each derivative to 1e-10 of its largest size over the joints
        close(out.qd, x[:, 1])
        if order == 3:
            close(out.qdd, x[:, 2])
        if steady:
            assert Ps is None
        else:
            close(Ps, P, axis=0)


def close(a, b, axis=None, rel=1e-12):
    scale = np.abs(b).max(axis=axis, keepdims=True)
    np.testing.assert_allclose(np.asarray(a) / scale, b / scale, rtol=0, atol=rel)


def manus2_acceleration(x, tau):
    """q̈ of the thesis's arm (eqs. C.1–C.5) with viscous and Coulomb friction in a boundary layer,
    numpy, complex-step safe."""
    q1, q2, v1, v2 = x
    c, s = np.cos(q2 - q1), np.sin(q2 - q1)
    sat = lambda v: np.where(abs(v.real) < PHI, v / PHI, np.sign(v.real))
    r = (
        tau
        - np.array([-A2 * s * v2**2, A2 * s * v1**2])
        - np.array([B[0] * v1, B[1] * v2])
        - np.array([FC[0] * sat(v1), FC[1] * sat(v2)])
    )
    det = A1 * A3 - (A2 * c) ** 2
    return np.array([A3 * r[0] - A2 * c * r[1], A1 * r[1] - A2 * c * r[0]]) / det


def manus2_transition(x, tau):
    a = manus2_acceleration(x, tau)
    return np.concatenate([x[:2] + DT * x[2:] + 0.5 * DT**2 * a, x[2:] + DT * a])


def complex_step_jacobian(f, x, h=1e-30):
    return np.stack([f(x + 1j * h * e).imag / h for e in np.eye(len(x))], 1)


def test_model_kalman_equals_filterpy_ekf_on_the_thesis_arm(motion):
    q, tau = motion
    est = estimators.make("kalman_model", n_joints=2, q=3e-3)
    assert isinstance(est, ModelKalman)

    class ArmEKF(ExtendedKalmanFilter):
        def predict_x(self, u=0):
            self.x = manus2_transition(self.x[:, 0], u)[:, None]

    ekf = ArmEKF(dim_x=4, dim_z=2)
    ekf.x = np.concatenate([q[0], [0.0, 0.0]])[:, None]
    ekf.P, ekf.R = np.array(est.P0), R * np.eye(2)
    ekf.Q = np.kron(Q_continuous_white_noise(2, DT, 3e-3), np.eye(2))  # pyright: ignore[reportCallIssue, reportArgumentType]
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    ref, prev = [], np.zeros(2)
    for k in range(len(q)):
        ekf.F = complex_step_jacobian(lambda x, u=prev: manus2_transition(x, u), ekf.x[:, 0].astype(complex))
        ekf.predict(u=prev)  # pyright: ignore[reportArgumentType]
        ekf.update(q[k][:, None], lambda x: H, lambda x: H @ x)
        ref.append(ekf.x[2:, 0].copy())
        prev = tau[k]
    agree(est, q, tau, np.array(ref))


def test_luenberger_places_both_poles_at_the_bandwidth_and_equals_numpy(motion):
    q, tau = motion
    est = estimators.make("luenberger", bandwidth=300.0)
    assert isinstance(est, Luenberger)
    l1, l2 = np.asarray(est.gains)
    F = np.array([[1.0, DT], [0.0, 1.0]])
    closed = (np.eye(2) - np.outer([l1, l2], [1.0, 0.0])) @ F
    z = np.exp(-300.0 * DT)
    np.testing.assert_allclose(np.poly(closed), [1.0, -2 * z, z * z], atol=1e-12)
    x, ref = np.stack([q[0], np.zeros(2)]), []
    for y in q:
        x = F @ x
        x = x + np.outer([l1, l2], y - x[0])
        ref.append(x[1].copy())
    agree(est, q, tau, np.array(ref))


def test_model_luenberger_equals_numpy_on_the_thesis_arm(motion):
    q, tau = motion
    est = estimators.make("luenberger_model", n_joints=2, bandwidth=200.0)
    assert isinstance(est, Luenberger)
    l1, l2 = np.asarray(est.gains)
    x, ref, prev = np.concatenate([q[0], [0.0, 0.0]]), [], np.zeros(2)
    for k in range(len(q)):
        x = manus2_transition(x, prev)
        e = q[k] - x[:2]
        x = x + np.concatenate([l1 * e, l2 * e])
        ref.append(x[2:].copy())
        prev = tau[k]
    agree(est, q, tau, np.array(ref))


def test_levant_solves_its_implicit_step(motion):
    q, tau = motion
    L = 200.0
    c, b = DT * DT * K2 * L, DT * K1 * np.sqrt(L)
    z0, z1, ref = q[0].copy(), np.zeros(2), []
    for f in q:
        for j in range(2):
            w = z0[j] + DT * z1[j] - f[j]
            if abs(w) <= c:  # on the sliding set: e = 0, s = w / c ∈ [−1, 1]
                e, s = 0.0, w / c
            else:  # off it: s = sgn e = sgn w, and e solves e − w + c s + b ⌈e⌋^½ = 0
                s = np.sign(w)
                e = float(
                    scipy.optimize.brentq(  # pyright: ignore[reportArgumentType]
                        lambda e, w=w, s=s: e - w + c * s + b * np.sign(e) * np.sqrt(abs(e)),
                        0.0,
                        w,
                        xtol=1e-300,
                        rtol=4 * np.finfo(float).eps,
                    )
                )
            # the implicit Euler step, as written in the differentiator's equations
            z1[j] = z1[j] - DT * K2 * L * s
            z0[j] = z0[j] + DT * (-K1 * np.sqrt(L) * np.sign(e) * np.sqrt(abs(e)) + z1[j])
            assert abs(z0[j] - f[j] - e) < 1e-12
        ref.append(z1.copy())
    agree(estimators.make("levant", lipschitz=L), q, tau, np.array(ref))


def test_foaw_equals_the_papers_loop(motion):
    q, tau = motion
    d, N = 1.37 * STEP, 20  # not a multiple of Δ/2: no ties on the band's edge
    hist = [q[0]] * N  # at rest before the first sample
    ref = []
    for y in q:
        hist = [y] + hist[:N]
        v = np.zeros(2)
        for j in range(2):
            yk = [h[j] for h in hist]
            for n in range(1, N + 1):  # widen the window while a line fits every sample in it
                b = (n * sum(yk[: n + 1]) - 2 * sum(i * yk[i] for i in range(n + 1))) / (DT * n * (n + 1) * (n + 2) / 6)
                if any(abs(yk[i] - (yk[0] - b * i * DT)) > d for i in range(1, n)):
                    break
                v[j] = b
        ref.append(v)
    agree(estimators.make("foaw", d=d, window=N), q, tau, np.array(ref))
