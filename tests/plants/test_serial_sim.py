"""Simulating a serial chain: the coupled stick-slip step against a direct solution, and the
simulator's serial robot against the equations of motion it integrates (pinocchio's ABA)."""

import numpy as np
import pytest
import scipy.optimize

import jax
import jax.numpy as jnp

from manus.plants.serial_friction import ROUNDS, SWEEPS, Dense, box_friction, pgs
from tests.plants.test_serial import load


def _direct(H: np.ndarray, v: np.ndarray, lo: np.ndarray, hi: np.ndarray, dt: float) -> np.ndarray:
    """min ½ fᵀWf − fᵀv over the box, W = dt H⁻¹, as bounded least squares (scipy's BVLS, an
    active-set method that ends at the exact solution): with W = L Lᵀ the objective is
    ½‖Lᵀf − L⁻¹v‖² up to a constant."""
    W = dt * np.linalg.inv(H)
    W = 0.5 * (W + W.T)
    on = np.maximum(lo, hi) > 0  # a joint without friction has f = 0 (and BVLS wants lo < hi)
    L = np.linalg.cholesky(W[np.ix_(on, on)])
    f = np.zeros_like(v)
    f[on] = scipy.optimize.lsq_linear(L.T, np.linalg.solve(L, v[on]), bounds=(-lo[on], hi[on]), method="bvls",
                                      tol=1e-14).x
    return f


def _cases(count: int, seed: int):
    """Random Panda configurations with random armature (some joints without), friction levels
    (some zero) and velocities scaled so that joints stick, slide and mix."""
    _, serial, _, _ = load("panda")
    rng = np.random.default_rng(seed)
    n = serial.n_joints
    q = rng.uniform(-np.pi, np.pi, (count, n))
    theta = np.tile(serial.defaults, (count, 1))
    theta[:, -n:] = rng.uniform(0, 0.3, (count, n)) * (rng.random((count, n)) < 0.7)
    H = np.asarray(jax.jit(jax.vmap(serial.mass_matrix))(q, theta))
    dt = 1e-4
    levels = rng.uniform(0, 2, (count, 2, n)) * (rng.random((count, 1, n)) < 0.9)
    push = rng.standard_normal((count, n)) * rng.uniform(0.1, 4, (count, 1))  # torques of the order of the levels
    v = dt * np.linalg.solve(H, push[..., None])[..., 0]
    return H, v, levels[:, 0], levels[:, 1], dt


def test_the_friction_step_is_the_exact_box_qp_solution():
    H, v, lo, hi, dt = _cases(400, seed=1)
    f, exact = jax.jit(jax.vmap(lambda *x: box_friction(*x, dt)))(H, v, lo, hi)
    start = jnp.clip(jnp.einsum("kij,kj->ki", H, v) / dt, -lo, hi)
    W = dt * np.linalg.inv(H)
    pgs_only = jax.jit(jax.vmap(lambda W, v, lo, hi, f: pgs(W, v, lo, hi, f, ROUNDS * SWEEPS)))(W, v, lo, hi, start)
    scale = np.maximum(lo, hi).max(1)
    err, err_pgs, free = [], [], []
    for k in range(len(v)):
        ref = _direct(H[k], v[k], lo[k], hi[k], dt)
        err.append(np.abs(f[k] - ref).max() / scale[k])
        err_pgs.append(np.abs(pgs_only[k] - ref).max() / scale[k])
        free.append(int(np.sum((ref > -lo[k] + 1e-9) & (ref < hi[k] - 1e-9))))
    print(f"box QP, {len(v)} cases (joints stuck per case: {np.bincount(free).tolist()}): polished max error "
          f"{max(err):.2g} of the levels, confirmed exact {np.mean(exact):.1%}; PGS alone after {ROUNDS * SWEEPS} sweeps "
          f"{max(err_pgs):.2g} (median {np.median(err_pgs):.2g})")
    assert np.all(exact) and max(err) < 1e-9
    assert len(set(free)) >= 5  # the cases mix sliding and stuck joints


def test_a_stuck_joint_rests_exactly_and_a_sliding_one_feels_its_level():
    H, _, _, _, dt = _cases(1, seed=2)
    H = H[0]
    n = H.shape[0]
    lo = hi = np.full(n, 0.5)
    v = np.zeros(n)
    v[0] = 1.0  # joint 1 fast: it slides; the others at rest, held by their friction
    f, exact = box_friction(H, v, lo, hi, dt)
    vel = v - dt * np.linalg.solve(H, np.asarray(f))
    assert exact and f[0] == pytest.approx(0.5, abs=0)  # sliding forward: exactly its level
    np.testing.assert_allclose(vel[1:], 0.0, atol=1e-15)  # the others stay at rest
    # the dense matrix's other services
    D = Dense(jnp.asarray(H))
    r = tuple(jnp.arange(1.0, n + 1))
    np.testing.assert_allclose(jnp.stack(D.solve(r)), np.linalg.solve(H, np.arange(1.0, n + 1)), rtol=1e-12)
    np.testing.assert_allclose(jnp.stack(D.diagonal()), np.diag(H), rtol=0)
    np.testing.assert_allclose(D.minus_diagonal(tuple(jnp.ones(n))).matrix(), H - np.eye(n), rtol=0)
