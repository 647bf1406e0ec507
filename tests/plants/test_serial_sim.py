"""Simulating a serial chain: the coupled stick-slip step against a direct solution, and the
simulator's serial robot against the equations of motion it integrates (pinocchio's ABA)."""

from pathlib import Path
from typing import cast

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.optimize

from manus.plants.serial import Serial
from manus.plants.serial_friction import ROUNDS, SWEEPS, Dense, box_friction, pgs
from tests.plants.test_serial import ROBOTS, load


def _direct(H: np.ndarray, v: np.ndarray, lo: np.ndarray, hi: np.ndarray, dt: float) -> np.ndarray:
    """min ½ fᵀWf − fᵀv over the box, W = dt H⁻¹, as bounded least squares (scipy's BVLS, an
    active-set method that ends at the exact solution): with W = L Lᵀ the objective is
    ½‖Lᵀf − L⁻¹v‖² up to a constant."""
    W = dt * np.linalg.inv(H)
    W = 0.5 * (W + W.T)
    on = np.maximum(lo, hi) > 0  # a joint without friction has f = 0 (and BVLS wants lo < hi)
    L = np.linalg.cholesky(W[on][:, on])
    f = np.zeros_like(v)
    f[on] = scipy.optimize.lsq_linear(
        L.T, np.linalg.solve(L, v[on]), bounds=(-lo[on], hi[on]), method="bvls", tol=1e-14
    ).x
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
    H, v, lo, hi, dt = _cases(200, seed=1)
    f, exact = jax.jit(jax.vmap(lambda H, v, lo, hi: box_friction(H, v, lo, hi, dt)))(H, v, lo, hi)
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
    print(
        f"box QP, {len(v)} cases (joints stuck per case: {np.bincount(free).tolist()}): polished max error "
        f"{max(err):.2g} of the levels, confirmed exact {np.mean(exact):.1%}; PGS alone after {ROUNDS * SWEEPS} sweeps "
        f"{max(err_pgs):.2g} (median {np.median(err_pgs):.2g})"
    )
    assert np.all(exact) and max(err) < 1e-9
    assert len(set(free)) >= 5  # the cases mix sliding and stuck joints


def test_a_stuck_joint_rests_exactly_and_a_sliding_one_feels_its_level():
    H, _, _, _, dt = _cases(1, seed=2)
    H = H[0]
    n = H.shape[0]
    lo = hi = np.full(n, 0.5)
    v = np.zeros(n)
    v[0] = 1.0  # joint 1 fast: it slides; the others at rest, held by their friction
    f, exact = jax.jit(box_friction)(H, v, lo, hi, dt)
    vel = v - dt * np.linalg.solve(H, np.asarray(f))
    assert exact and f[0] == pytest.approx(0.5, abs=0)  # sliding forward: exactly its level
    np.testing.assert_allclose(vel[1:], 0.0, atol=1e-15)  # the others stay at rest
    # the dense matrix's other services
    D = Dense(jnp.asarray(H))
    r = tuple(jnp.arange(1.0, n + 1))
    np.testing.assert_allclose(jnp.stack(D.solve(r)), np.linalg.solve(H, np.arange(1.0, n + 1)), rtol=1e-12)
    np.testing.assert_allclose(jnp.stack(D.diagonal()), np.diag(H), rtol=0)
    np.testing.assert_allclose(D.minus_diagonal(tuple(jnp.ones(n))).matrix(), H - np.eye(n), rtol=0)


# -- the simulator's serial robot -----------------------------------------------------------------


def _simulate(model, params, q0, commands, periods, substeps=10):
    """(q, q̇) per period under each constant command of `commands` (one compiled run for all)."""
    from manus.plants.simulator import Simulator

    sim = Simulator(model, params, substeps=substeps, actuator=None, encoder=None, q0=q0)
    state, _ = sim.reset()

    @jax.jit
    def run(command):
        def tick(state, _):
            state, _ = sim.step(state, command)
            return state, (state.q, state.qd)

        return jax.lax.scan(tick, state, None, length=periods)[1]

    out = [run(jnp.asarray(c)) for c in commands]
    return [(np.asarray(q), np.asarray(qd)) for q, qd in out]


def test_the_simulated_panda_follows_pinocchios_forward_dynamics():
    """Rigid plus viscous friction under a constant torque: the simulator's Störmer–Verlet sub-steps
    against RK4 on pinocchio's ABA (articulated-body algorithm, an independent forward dynamics)."""
    pin = pytest.importorskip("pinocchio")
    from manus.plants.effects import Model

    _, serial, model, data = load("panda")
    n = serial.n_joints
    b = np.linspace(0.5, 0.2, n)
    q0 = np.array([0.1, -0.4, 0.2, -2.0, 0.3, 1.6, 0.7])
    tau = np.array(pin.rnea(model, data, q0, np.zeros(n), np.zeros(n))) + np.linspace(
        2.0, -1.0, n
    )  # gravity held, plus a push
    m = Model(serial, "rigid,viscous")
    [(q, qd)] = _simulate(m, {f"b{i + 1}": b[i] for i in range(n)}, q0, [tau], periods=200)

    def f(x):
        return np.r_[x[n:], pin.aba(model, data, x[:n], x[n:], tau - b * x[n:])]

    ref = rk4(f, np.r_[q0, np.zeros(n)])
    moved = np.abs(ref[-1, :n] - q0).max()
    err_q, err_v = np.abs(q - ref[:, :n]).max(), np.abs(qd - ref[:, n:]).max()
    print(f"Panda 0.2 s, moved up to {moved:.3g} rad: |q − q_ABA| ≤ {err_q:.2g} rad, |q̇ − q̇_ABA| ≤ {err_v:.2g} rad/s")
    assert moved > 0.05 and err_q < 1e-6 * max(1.0, moved) and err_v < 1e-5


def rk4(f, x, h: float = 1e-4, steps: int = 2000, every: int = 10) -> np.ndarray:
    """Classical RK4 of ẋ = f(x) from `x`, `steps` steps of `h`; the state after every `every`-th
    (the reference the simulator's periods are compared with)."""
    out = []
    for k in range(steps):
        k1 = f(x)
        k2 = f(x + h / 2 * k1)
        k3 = f(x + h / 2 * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        if k % every == every - 1:
            out.append(x.copy())
    return np.array(out)


def test_joints_held_by_friction_rest_exactly_and_a_pushed_one_breaks_away():
    """Gravity compensated, every joint under its Coulomb level: nothing moves, exactly. Joint 4
    pushed beyond its level: it slides, and the joints whose friction holds them stay at rest
    while it moves (their H coupling asks less than their level)."""
    pin = pytest.importorskip("pinocchio")
    from manus.plants.effects import Model

    _, serial, model, data = load("panda")
    n = serial.n_joints
    q0 = np.array([0.1, -0.4, 0.2, -2.0, 0.3, 1.6, 0.7])
    g = np.array(pin.rnea(model, data, q0, np.zeros(n), np.zeros(n)))
    m = Model(serial, "rigid,viscous,coulomb")
    params = {**{f"b{i + 1}": 0.1 for i in range(n)}, **{f"Fc{i + 1}": 2.0 for i in range(n)}}
    below = g + 1.5 * np.sin(np.arange(n) + 1.0)  # under every level (|·| ≤ 1.5 < 2)
    push = below.copy()
    push[3] = g[3] + 6.0
    (q, qd), pushed = _simulate(m, params, q0, [below, push], periods=100)
    assert np.all(qd == 0) and np.all(q == q0)
    q, qd = pushed
    assert qd[-1, 3] > 0.05
    resting = [j for j in range(n) if np.all(qd[:, j] == 0)]
    print("joint 4 pushed: joints still exactly at rest:", [j + 1 for j in resting])
    assert len(resting) >= 3 and 3 not in resting


def test_a_simulated_panda_recording_says_structure_urdf(tmp_path):
    from manus.plants import Model, Simulator, recording
    from manus.plants.serial_sim import Fourier, record

    _, serial, _, _ = load("panda")
    centre = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
    sim = Simulator(Model(serial, "rigid,viscous"), substeps=2, actuator=None, q0=centre)
    rec = record(sim, Fourier(centre, 0.3, 0.5, 3, seed=2), 0.3)
    assert rec.meta["structure"] == "urdf" and rec.structure is serial and len(rec) == 300
    tracking = np.abs(rec.q - np.stack([rec.extra[f"qref{i + 1}"] for i in range(7)], 1)).max()
    assert tracking < 0.01  # the feed-forward controller holds the arm up along the reference
    path = recording.write(rec, tmp_path / "panda.csv")
    back = recording.read(path)
    assert back.structure_name == "urdf" and cast(Path, back.robot).resolve() == Path(serial.source).resolve()
    assert cast(Serial, back.structure).joint_names == serial.joint_names and back.n_joints == 7


def test_a_chain_in_its_base_form_is_simulated_with_every_parameter_traced():
    """Output error builds the simulator inside a compiled function, the identified model (a
    chain's base parameters) traced with it: every parameter given, no default is read."""
    import equinox as eqx

    from manus.adaptive.identify.columns import identified
    from manus.plants import Model, Simulator

    serial = load(sorted(ROBOTS)[0])[1]
    model = Model(identified(serial), "rigid,viscous")
    params = {k: jnp.asarray(v) for k, v in model.defaults().items()}

    @eqx.filter_jit
    def first_step(model, params):
        sim = Simulator(model, params, actuator=None, encoder=None)
        state, _ = sim.reset(None, jnp.zeros(model.n_joints), jnp.zeros(model.n_joints))
        return sim.step(state, jnp.zeros(model.n_joints))[0].q

    q = first_step(model, params)
    assert q.shape == (model.n_joints,) and bool(jnp.all(jnp.isfinite(q)))
