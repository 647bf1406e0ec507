"""The Slotine–Li stepper: against an independent numpy implementation tick by tick, scan vs a
Python loop vs the closed loop, the composite law's prediction error, model-based estimators fed
with the estimates, and bad input (errors before the run, a safe stop during it)."""

from typing import cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.adaptive import Composite, SlotineLi, make_controller, replay, rollout
from manus.adaptive.regressors import Regressor
from manus.adaptive.slotine_li import fusion_boundary, regressor_entries, rollout_batch
from manus.estimators.base import Estimate, Estimator, FirstDifference
from manus.plants import Model, Simulator
from manus.plants.closed_loop import simulate
from manus.plants.errors import ManusError
from manus.plants.references import Complex
from manus.plants.structures import Axis, Manus2

TRUTH = Model(Manus2(), "rigid,viscous")
THETA = np.array([0.349, 0.241, 0.246, 0.222, 0.181])


@pytest.fixture(scope="module")
def run():
    """1 s of the complex trajectory under the controller, from estimates 30 % off."""
    plant = Simulator(TRUTH)
    ctrl = SlotineLi(TRUTH, estimator=FirstDifference(), theta0=0.7 * THETA, lead=0.0005)
    traj = simulate(plant, ctrl, Complex(), 1.0)
    refs = jax.vmap(Complex())(jnp.asarray(traj.t))
    return ctrl, traj, refs


def numpy_controller(q, refs, theta, gamma, lam=5.0, kd=5.0, dt=1e-3, lead=0.0005, lag=0.0005, limit=22.2):
    """The law of adaptive/slotine_li.py written out for MANUS-2 with rigid,viscous, first difference."""
    taus, thetas = [], []
    q_prev, qdd_prev = q[0], None
    for k in range(len(q)):
        qd_d, qdd_d, q_d = np.asarray(refs.qd[k]), np.asarray(refs.qdd[k]), np.asarray(refs.q[k])
        v = (q[k] - q_prev) / dt + lag * qdd_d
        q_prev = q[k]
        e, ev = q[k] - q_d, v - qd_d
        s = ev + lam * e
        jerk = 0 * qdd_d if qdd_prev is None else (qdd_d - qdd_prev) / dt
        qdd_prev = qdd_d
        qd_r = qd_d + lead * qdd_d + 0.5 * lead**2 * jerk - lam * e
        qdd_r = qdd_d + lead * jerk - lam * ev
        qp = q[k] + lead * v
        c, sn = np.cos(qp[1] - qp[0]), np.sin(qp[1] - qp[0])
        Y = np.array(
            [
                [qdd_r[0], c * qdd_r[1] - sn * v[1] * qd_r[1], 0, qd_r[0], 0],
                [0, c * qdd_r[0] + sn * v[0] * qd_r[0], qdd_r[1], 0, qd_r[1]],
            ]
        )
        taus.append(np.clip(Y @ theta - kd * s, -limit, limit))
        theta = theta - dt * gamma * (Y.T @ s)
        thetas.append(theta)
    return np.array(taus), np.array(thetas)


def test_the_law_matches_an_independent_numpy_implementation_tick_by_tick(run):
    ctrl, traj, refs = run
    assert ctrl.velocity_lag == pytest.approx(0.0005, abs=1e-9)  # measured: half a period
    states, tau = replay(ctrl, traj.q, refs)
    ref_tau, ref_theta = numpy_controller(traj.q, refs, 0.7 * THETA, np.asarray(ctrl.gamma))
    np.testing.assert_allclose(tau, ref_tau, atol=1e-10)
    np.testing.assert_allclose(states.theta, ref_theta, atol=1e-12)
    np.testing.assert_allclose(tau, traj.tau, atol=1e-12)  # replay = the closed loop
    assert np.abs(ref_theta[-1] - ref_theta[0]).max() > 0.01  # it adapted


def test_a_python_loop_over_the_jitted_step_agrees_with_the_scan(run):
    ctrl, traj, refs = run
    step = eqx.filter_jit(ctrl.step)
    state = ctrl.init(jnp.asarray(traj.q[0]))
    _, tau = replay(ctrl, traj.q[:200], jax.tree.map(lambda x: x[:200], refs))
    for k in range(200):
        state, u = step(state, jnp.asarray(traj.q[k]), jax.tree.map(lambda x, k=k: x[k], refs))
        np.testing.assert_allclose(u, tau[k], atol=1e-13)


def test_composite_prediction_error_of_the_true_parameters_is_small_and_timing_matters():
    """Filtered torque against the filtered regressor on an ideal plant run with the truth:
    about 1e-3 N·m when the command timing is right, several times more one period off."""
    plant = Simulator(TRUTH, actuator=None, encoder=None)
    ctrl = SlotineLi(TRUTH, theta0=THETA, gamma=1e-12, lead=0.0005)
    traj = simulate(plant, ctrl, Complex(), 1.5)
    qdd_d = np.asarray(jax.vmap(Complex())(jnp.asarray(traj.t)).qdd)
    v = np.diff(traj.q, axis=0, prepend=traj.q[:1]) / 1e-3 + 0.0005 * qdd_d  # the controller's velocity
    comp = Composite(bandwidth=10.0)

    def residual(lead):
        def body(st, x):
            st, W, tau_f = comp.step(st, ctrl.regressor, x[0], x[1], x[2], ctrl.gamma, lead, 1e-3)
            return st, W @ THETA - tau_f

        _, e = jax.lax.scan(
            body, comp.init(ctrl.regressor, ctrl.gamma), (jnp.asarray(traj.q), jnp.asarray(v), jnp.asarray(traj.tau))
        )
        return np.sqrt(np.mean(np.asarray(e)[500:] ** 2))

    good, off = residual(0.0005), residual(0.0015)
    assert good < 2e-3
    assert off > 5 * good


def test_composite_gain_stays_symmetric_positive_definite_and_shrinks(run):
    _, traj, refs = run
    ctrl = cast(SlotineLi, make_controller("slotine-li-composite", TRUTH, 1e-3, theta0=0.7 * THETA))
    states, _ = replay(ctrl, traj.q, refs)  # the controller cannot tell a recording from its own loop
    P = np.asarray(states.composite.P[-1])
    np.testing.assert_allclose(P, P.T, atol=1e-14)
    assert np.linalg.eigvalsh(P)[0] > 0
    assert np.all(np.diag(P) < np.asarray(ctrl.gamma))


class NaNAfter(Estimator):
    """A first difference that reports NaN from tick `k` on."""

    dt: float = 1e-3
    k: int = 300

    def init(self, q0):
        return jnp.asarray(q0, float), jnp.array(0)

    def step(self, state, q, tau=None):
        q_prev, i = state
        v = jnp.where(i >= self.k, jnp.nan, (q - q_prev) / self.dt)
        return (q, i + 1), Estimate(q, v)


def test_a_nan_from_the_estimator_stops_safely_and_keeps_the_data():
    ctrl = SlotineLi(TRUTH, estimator=NaNAfter(), theta0=0.7 * THETA)
    log, _ = eqx.filter_jit(rollout)(Simulator(TRUTH), ctrl, Complex(), 600)
    assert log.tau.shape == (600, 2) and np.all(np.isfinite(log.q))  # the whole run is there
    assert np.all(log.tau[300:] == 0) and np.abs(log.tau[:300]).min(0).max() > 0
    assert bool(log.stopped[-1]) and not bool(log.stopped[299])
    np.testing.assert_array_equal(log.theta[-1], log.theta[299])  # frozen, finite
    assert np.all(np.isfinite(log.theta)) and np.abs(log.theta[299] - log.theta[0]).max() > 0


def test_a_model_based_estimator_gets_the_current_estimates(run):
    _, traj, refs = run
    ctrl = make_controller("slotine-li", TRUTH, 1e-3, "kalman_model", theta0=0.7 * THETA)
    states, _ = replay(ctrl, traj.q[:300], jax.tree.map(lambda x: x[:300], refs))
    fed = np.asarray(states.estimator.theta)  # what the estimator predicted with at each tick
    np.testing.assert_allclose(fed[1:], states.theta[:-1], atol=1e-15)
    assert np.abs(fed[-1] - fed[0]).max() > 1e-3


@pytest.mark.parametrize(
    "gains, match",
    [
        ({"gamma": {"a2": 0.0}}, r"gamma must be positive definite.*a2=0"),
        ({"gamma": -1.0}, r"gamma must be positive definite"),
        ({"lam": [5.0, -1.0]}, r"lam must be positive definite.*joint2=-1"),
        ({"kd": float("nan")}, r"kd must be positive definite"),
        ({"gamma": [0.2, 0.2]}, r"gamma: expected 5 values"),
        ({"theta0": {"a9": 1.0}}, r"theta0: unknown name\(s\) a9"),
        ({"lead": -0.001}, r"lead must be a time"),
    ],
)
def test_bad_gains_are_refused_before_the_run(gains, match):
    with pytest.raises(ManusError, match=match):
        SlotineLi(TRUTH, **gains)


def test_a_model_that_does_not_match_the_plant_is_refused_before_the_run():
    ctrl = SlotineLi(Model(Axis(n_joints=3), "rigid,viscous"))
    with pytest.raises(ManusError, match="has 3 joint\\(s\\) but the plant measures 2"):
        simulate(Simulator(TRUTH), ctrl, Complex(), 0.1)
    with pytest.raises(ManusError, match=r"runs at dt = 0\.002 s but the controller at 0\.001 s"):
        SlotineLi(TRUTH, estimator=FirstDifference(dt=0.002))


def test_the_regressor_entry_by_entry_is_the_regressors_array():
    """`regressor_entries` (rigid columns written out, every other column its effect's torque with
    that parameter 1) against `Regressor.__call__` (forward-mode differentiation), bit for bit."""
    reg = Regressor(Model(Manus2(), "rigid,viscous,coulomb,stribeck,asymmetry,gravity,cogging"))
    args = jnp.asarray(np.random.default_rng(0).normal(0, 1, (4, 40, 2)))
    args = args.at[2, ::2].multiply(1e-3)  # inside and outside the Coulomb boundary layer
    entries = jax.jit(jax.vmap(lambda *a: jnp.stack([jnp.stack(row) for row in regressor_entries(reg, *a)])))(*args)
    np.testing.assert_array_equal(np.asarray(entries), np.asarray(jax.jit(jax.vmap(reg))(*args)))


def test_the_fusion_boundary_returns_its_input_bit_for_bit_under_vmap():
    x = jnp.array([[1.5, -0.0, jnp.nan], [jnp.inf, 0.0, -2.0]])
    out = jax.jit(jax.vmap(lambda r: fusion_boundary((r[0], [r[1], r[2]]))))(x)
    for got, want in zip(jax.tree.leaves(out), (x[:, 0], x[:, 1], x[:, 2]), strict=True):
        np.testing.assert_array_equal(np.signbit(got), np.signbit(want))
        np.testing.assert_array_equal(got, want)
    out = jax.jit(jax.vmap(lambda r: fusion_boundary((r[0], [r[1], r[2]]))))(x[::-1])  # NaN first: the other branch
    np.testing.assert_array_equal(jax.tree.leaves(out)[2], x[::-1, 2])


def test_the_batch_keeps_the_statistics_of_every_tick_and_a_row_of_every_fifth():
    """`rollout_batch` (vmapped, every entry a batch vector, a record of every 5th tick and the
    statistics of every tick) against `rollout` (every tick logged) trial by trial: the rows, the
    estimates, ∫YᵀY dt, the settle times (numpy on the full log), the mean square tracking error
    and the largest command. (`trial`, the same scans unbatched, is `manus bench converge`'s.)"""
    from manus.experiments.convergence import settle_times

    truth_model = Model(Manus2(), "rigid,viscous,coulomb")
    plant = Simulator(truth_model, torque_noise=0.005)
    ctrl = SlotineLi(truth_model, lead=0.0015)
    truth = np.array([float(plant.params[k]) for k in ctrl.names])
    theta0 = truth * np.array([[1.3, 0.8, 1.2, 0.5, 1.5, 1.4, 0.6], [0.1, 1.9, 0.1, 1.0, 1.0, 1.0, 1.0], [1.0] * 7])
    per_trial = (
        jnp.asarray(theta0),
        *(
            jnp.broadcast_to(x, (3,) + x.shape) * jnp.array([1.0, 1.2, 0.8])[:, None]
            for x in (ctrl.gamma, ctrl.lam, ctrl.kd)
        ),
    )
    keys = jax.random.split(jax.random.PRNGKey(4), 3)
    steps, every, record = 600, 50, 5
    batch = rollout_batch(plant, ctrl, Complex(), per_trial, keys, steps, every, record)
    np.testing.assert_allclose(batch.t, (np.arange(steps // record) * record + record - 1) * 1e-3)
    full = eqx.filter_jit(rollout)
    for i in range(3):
        c = eqx.tree_at(lambda c: (c.theta0, c.gamma, c.lam, c.kd), ctrl, tuple(x[i] for x in per_trial))
        log, grams = full(plant, c, Complex(), steps, keys[i], every)
        q_err, theta = np.asarray(log.q - log.q_ref), np.asarray(log.theta)
        close = lambda got, want: np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)  # vector vs scalar code
        close(batch.q_err[i], q_err[record - 1 :: record])
        close(batch.tau[i], np.asarray(log.tau)[record - 1 :: record])
        close(batch.theta[i], theta[record - 1 :: record])
        close(batch.theta_final[i], theta[-1])
        close(batch.grams[i], np.asarray(grams))
        close(batch.q_err_ms[i], np.mean(q_err**2, axis=0))
        close(batch.tau_max[i], np.abs(np.asarray(log.tau)).max(0))
        for k in range(len(truth)):
            want = settle_times(np.asarray(log.t), theta[None, :, k], truth[k])[0]
            assert batch.settle[i, k] == pytest.approx(want, nan_ok=True), (i, k)
    assert np.isfinite(batch.settle).any() and np.isnan(batch.settle).any()  # both kinds of trial
    assert not batch.stopped.any()
