"""The simulator against independent references: numpy RK4, energy, the sensor chain, stiction,
the shaft mode, and batch against one-by-one."""

import json
import math
import pathlib
import subprocess
import sys
from typing import cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.adaptive.impedance import Impedance
from manus.plants import Actuator, Model, Simulator
from manus.plants.closed_loop import simulate, simulate_batch
from manus.plants.effects import is_dry, is_load
from manus.plants.references import Complex, MultiSine
from manus.plants.structures import Axis, Manus2

A1, A2, A3, B1, B2 = 0.349, 0.241, 0.246, 0.222, 0.181


def open_loop(sim, taus, **reset):
    """Drive `sim` with the commands `taus` (T, n); true (q, qd) before each command."""
    state, _ = sim.reset(**reset)
    run = eqx.filter_jit(
        lambda st, u: jax.lax.scan(lambda s, x: (sim.step(s, x)[0], (s.q, s.qd, sim.measure(s))), st, u)
    )
    _, out = run(state, jnp.asarray(taus, float))
    return tuple(np.asarray(x) for x in out)


def arm_rk4(x0, taus, per_period=10, dt=1e-3):
    """An independent numpy RK4 of eqs. 3.2–3.3 with viscous friction, torque held per period."""

    def f(x, tau):
        q1, q2, v1, v2 = x
        c, s = np.cos(q2 - q1), np.sin(q2 - q1)
        H = np.array([[A1, A2 * c], [A2 * c, A3]])
        r = tau - np.array([-A2 * s * v2**2, A2 * s * v1**2]) - np.array([B1 * v1, B2 * v2])
        return np.concatenate([[v1, v2], np.linalg.solve(H, r)])

    x, h, out = np.array(x0, float), dt / per_period, []
    for tau in taus:
        out.append(x.copy())
        for _ in range(per_period):
            k1 = f(x, tau)
            k2 = f(x + h / 2 * k1, tau)
            k3 = f(x + h / 2 * k2, tau)
            k4 = f(x + h * k3, tau)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return np.array(out)


def test_arm_matches_an_independent_rk4():
    t = np.arange(2000) * 1e-3
    taus = np.stack([0.3 * np.sin(2 * np.pi * 1.3 * t), -0.2 * np.cos(2 * np.pi * 0.7 * t)], 1)
    ref = arm_rk4([0.464, 2.409, 0.5, -0.8], taus)
    errors = []
    for substeps in (5, 20):
        sim = Simulator(Model(Manus2(), "rigid,viscous"), substeps=substeps, actuator=None, encoder=None)
        q, _, _ = open_loop(sim, taus, qd0=jnp.array([0.5, -0.8]))
        errors.append(np.abs(q - ref[:, :2]).max())
    assert errors[1] < 1e-7  # 2 s of motion, about 0.5 rad
    assert errors[0] / errors[1] > 10  # second order: 4x the sub-steps, ~16x smaller error


def test_energy_is_conserved_without_friction_or_torque():
    sim = Simulator(Model(Manus2(), "rigid"), actuator=None, encoder=None)
    q, qd, _ = open_loop(sim, np.zeros((10000, 2)), qd0=jnp.array([0.5, -0.8]))
    c = np.cos(q[:, 1] - q[:, 0])
    energy = 0.5 * (A1 * qd[:, 0] ** 2 + 2 * A2 * c * qd[:, 0] * qd[:, 1] + A3 * qd[:, 1] ** 2)
    assert np.abs(q[-1] - q[0]).min() > 1.0  # it really moved
    assert np.abs(energy / energy[0] - 1).max() < 1e-7


def test_positions_are_reported_on_the_encoder_grid():
    sim = Simulator(Model(Manus2(), "rigid,viscous,coulomb"))
    traj = simulate(sim, Impedance(), MultiSine(), 1.0)
    counts = traj.q / (2 * math.pi / 131072)
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    assert np.abs(traj.q - traj.q_true).max() <= math.pi / 131072 * (1 + 1e-9)
    assert len(np.unique(traj.q[:, 0])) > 100


def test_actuator_chain_quantizes_and_saturates():
    sim = Simulator(Model(Manus2(), "rigid"))
    lsb = 20 / 4096 * 0.6 * 3.7
    out = np.asarray(cast(Actuator, sim.actuator)(jnp.array([0.1234, 100.0, -100.0])))
    np.testing.assert_allclose(out, [round(0.1234 / lsb) * lsb, 2047 * lsb, -2048 * lsb])


def test_a_torque_step_shows_up_exactly_one_sample_later_with_the_delay():
    taus = np.zeros((50, 1))
    taus[20:] = 1.0
    plain = Simulator(Model(Axis(), "rigid,viscous"), actuator=None, encoder=None)
    late = Simulator(Model(Axis(), "rigid,viscous,delay"), actuator=None, encoder=None)
    q0, _, _ = open_loop(plain, taus)
    q1, _, _ = open_loop(late, taus)
    assert q0[20, 0] == 0 and q0[21, 0] > 0  # no delay: moves in the period after the step
    assert q1[21, 0] == 0 and q1[22, 0] > 0
    np.testing.assert_array_equal(q1[1:], q0[:-1])  # exactly one sample later


@pytest.mark.parametrize("delays", ["1ms/3ms", "0.5ms/2.5ms"])
def test_a_delay_per_joint_delays_each_joint_by_its_own(delays):
    """Two independent axes, one delay each (whole and fractional periods): each joint moves as
    it does in a simulation with its own delay for both."""
    taus = np.zeros((60, 2))
    taus[20:, 0], taus[25:, 1] = 1.0, -0.5
    both = Simulator(Model(Axis(n_joints=2), f"rigid,viscous,delay:{delays}"), actuator=None, encoder=None)
    q, _, _ = open_loop(both, taus)
    for j, d in enumerate(delays.split("/")):
        alone = Simulator(Model(Axis(n_joints=2), f"rigid,viscous,delay:{d}"), actuator=None, encoder=None)
        np.testing.assert_array_equal(q[:, j], open_loop(alone, taus)[0][:, j])
    assert both.delay == pytest.approx(max(float(d[:-2]) for d in delays.split("/")) * 1e-3)


def test_compliance_resonance_in_the_position_spectrum():
    """Thesis Figs. 4-18 to 4-20: a 10 Hz square wave, open loop, into the 1-DOF model with the
    shaft (m = 0.1, m2 = 0.9, k2 = 170000, b = 1.5, b2 = 2.0)."""
    sim = Simulator(Model(Axis(), "rigid,viscous,compliance"), actuator=None, encoder=None)
    t = np.arange(4000) * 1e-3
    taus = 4.0 * np.sign(np.sin(2 * np.pi * 10 * t + 1e-9))[:, None]
    _, qd, _ = open_loop(sim, taus)
    v = qd[1000:, 0] - qd[1000:, 0].mean()
    spec = np.abs(np.fft.rfft(v * np.hanning(len(v))))
    f = np.fft.rfftfreq(len(v), 1e-3)
    band = (f > 120) & (f < 400)
    peak = f[band][np.argmax(spec[band])]
    # the linear model's mode: eigenvalues of the two-mass system with the thesis's values
    m1, m2, k, b, b2 = 0.1, 0.9, 170000.0, 1.5, 2.0
    A = np.array(
        [[0, 0, 1, 0], [0, 0, 0, 1], [-k / m1, k / m1, -(b + b2) / m1, b2 / m1], [k / m2, -k / m2, b2 / m2, -b2 / m2]]
    )
    mode = np.abs(np.linalg.eigvals(A)).max() / (2 * np.pi)
    assert mode == pytest.approx(218.7, rel=0.01)
    assert peak == pytest.approx(mode, rel=0.05)
    # off-peak lines (the square wave's odd harmonics) are much weaker than the resonance
    assert spec[band].max() > 5 * np.median(spec[band])


def test_arm_with_compliance_rings_near_200_hz():
    sim = Simulator(Model(Manus2(), "rigid,viscous,coulomb,compliance"))
    t = np.arange(2000) * 1e-3
    taus = np.zeros((2000, 2))
    taus[:, 0] = 4.0 * np.sign(np.sin(2 * np.pi * 10 * t + 1e-9))
    _, _, meas = open_loop(sim, taus)
    x = np.diff(meas[500:, 0])
    spec = np.abs(np.fft.rfft((x - x.mean()) * np.hanning(len(x))))
    f = np.fft.rfftfreq(len(x), 1e-3)
    band = (f > 100) & (f < 400)
    assert 190 < f[band][np.argmax(spec[band])] < 240


def test_stiction_holds_at_rest_below_static_friction_and_breaks_away_above():
    model = Model(Manus2(), "rigid,viscous,coulomb,stribeck")
    sim = Simulator(model, actuator=None, encoder=None)
    static = np.array([0.099 + 0.05, 0.139 + 0.07])
    q, qd, _ = open_loop(sim, np.tile(0.95 * static, (1000, 1)) * [1, -1])
    # coupled inertia: joint 2 also feels joint 1's torque, but nothing can move
    assert np.all(q == q[0]) and np.all(qd == 0)
    q, qd, _ = open_loop(sim, np.tile(1.05 * static * [1, 0], (300, 1)))
    assert q[-1, 0] - q[0, 0] > 1e-4  # joint 1 breaks away
    assert np.all(q[:, 1] == q[0, 1])  # joint 2 held by its static friction


def test_a_sliding_joint_stops_where_the_closed_form_says_and_stays_stopped():
    """Unit masses, Fc = 0.5: joint 1 coasts from 0.5 m/s (deceleration 0.5), joint 2 from
    2 m/s against a −0.3 N push (deceleration 0.8), which cannot restart it once stopped."""
    sim = Simulator(Model(Axis(n_joints=2), "rigid,coulomb"), actuator=None, encoder=None)
    q, qd, _ = open_loop(sim, np.tile([0.0, -0.3], (3000, 1)), qd0=jnp.array([0.5, 2.0]))
    for j, (v0, decel) in enumerate([(0.5, 0.5), (2.0, 0.8)]):
        stop = np.argmax(qd[:, j] == 0)
        assert stop * 1e-3 == pytest.approx(v0 / decel, abs=2e-3)
        assert np.all(qd[stop:, j] == 0) and np.all(q[stop:, j] == q[stop, j])
        assert q[stop, j] - q[0, j] == pytest.approx(v0**2 / (2 * decel), rel=1e-3)


def test_the_torque_noise_is_white_and_gaussian_as_numpys_generator_is():
    """`white_noise` (counter-based Threefry, float32 erf⁻¹) against numpy's standard normal draws,
    the same statistics with the same bounds: mean, variance, autocorrelation at lags 1–5, the
    joints and two keys uncorrelated, the distribution (two-sample KS, the 3σ tails)."""
    from scipy.stats import ks_2samp

    from manus.plants.simulator import white_noise

    n_ticks, n = 100_000, 3  # three joints: two Threefry blocks per tick
    draw = jax.jit(jax.vmap(white_noise, in_axes=(None, 0, None)), static_argnums=2)
    ticks = jnp.arange(n_ticks, dtype=jnp.uint32)
    ours = np.asarray(draw(jax.random.PRNGKey(5), ticks, n), float)
    other_key = np.asarray(draw(jax.random.PRNGKey(6), ticks, n), float)
    numpys = np.random.default_rng(0).standard_normal((n_ticks, n))
    bound = 4.5 / math.sqrt(n_ticks)  # 4.5 standard errors of a correlation (or of a mean per draw)

    def corr(a, b):
        return float(np.mean((a - a.mean()) * (b - b.mean())) / (a.std() * b.std()))

    for z in (ours, numpys):
        assert np.all(np.isfinite(z))
        assert abs(z.mean()) < bound / math.sqrt(n)
        assert abs(z.var() - 1.0) < bound * math.sqrt(2.0 / n)
        for j in range(n):
            for lag in range(1, 6):
                assert abs(corr(z[lag:, j], z[:-lag, j])) < bound, (j, lag)
            assert abs(corr(z[:, j], z[:, (j + 1) % n])) < bound
        tails = np.mean(np.abs(z) > 3.0)  # 0.27 % for a Gaussian
        assert abs(tails - 0.0027) < 4.5 * math.sqrt(0.0027 / z.size)
    assert abs(corr(ours[:, 0], other_key[:, 0])) < bound
    assert ks_2samp(ours.ravel(), numpys.ravel()).pvalue > 1e-3  # pyright: ignore[reportAttributeAccessIssue]
    assert np.abs(ours).max() < 5.5  # 24 random bits per draw: the tails stop at 5.4


def test_the_plant_adds_the_noise_draw_of_each_period_to_the_held_torque():
    """A free unit mass per joint, no command: each period the velocity moves by σ z_k T exactly,
    z_k the draw of period k under the reset's key."""
    from manus.plants.simulator import white_noise

    sim = Simulator(Model(Axis(n_joints=2), "rigid"), actuator=None, encoder=None, torque_noise=0.1)
    _, qd, _ = open_loop(sim, np.zeros((501, 2)), key=jax.random.PRNGKey(9))
    z = jax.vmap(white_noise, in_axes=(None, 0, None))(jax.random.PRNGKey(9), jnp.arange(500, dtype=jnp.uint32), 2)
    np.testing.assert_allclose(np.diff(qd, axis=0) / (0.1 * 1e-3), np.asarray(z, float), rtol=1e-9, atol=1e-9)


def test_batch_equals_the_same_trials_one_by_one():
    plant = Simulator(Model(Manus2(), "rigid,viscous,coulomb,delay"), torque_noise=0.01)
    gains = jnp.array([10.0, 30.0, 60.0])
    controllers = eqx.filter_vmap(lambda k: Impedance(k, 1.0))(gains)
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    batch = simulate_batch(plant, controllers, Complex(), 0.5, keys, batched=("controller",))
    for i in range(3):
        one = simulate(plant, Impedance(float(gains[i]), 1.0), Complex(), 0.5, key=keys[i])
        np.testing.assert_allclose(batch.q[i], one.q, atol=1e-12)
        np.testing.assert_allclose(batch.tau[i], one.tau, atol=1e-12)
    assert not np.allclose(batch.q[0], batch.q[2])  # the trials really differ


# -- the fast path against the generic definitions ----------------------------------------------
# The simulator runs on per-joint scalars with closed-form 2×2 algebra, sin/cos turned by each
# sub-step's move and an exact closed form of the friction step; these tests hold it to the
# matrix forms (Structure.inertia/coriolis, Model.torque) and a brute-force box QP.


def box_qp(H, v, lo, hi, dt):
    """argmin ½ fᵀ(dt H⁻¹)f − fᵀv over −lo ≤ f ≤ hi by enumeration, vectorized over (N, 2)."""
    W = dt * np.linalg.inv(H)
    g = np.einsum("nij,nj->ni", H, v) / dt
    cands = [np.where(np.all((g >= -lo) & (g <= hi), 1, keepdims=True), g, np.nan)]
    for i, j in ((0, 1), (1, 0)):
        for bound in (-lo[:, i], hi[:, i]):
            f = np.empty_like(v)
            f[:, i] = bound
            f[:, j] = np.clip((v[:, j] - W[:, j, i] * bound) / W[:, j, j], -lo[:, j], hi[:, j])
            cands.append(f)
    cands = np.stack(cands)  # (9, N, 2)
    obj = 0.5 * np.einsum("cni,nij,cnj->cn", cands, W, cands) - np.einsum("cni,ni->cn", cands, v)
    return cands[np.nanargmin(np.where(np.isnan(obj), np.inf, obj), 0), np.arange(len(v))]


def test_the_friction_step_is_the_exact_box_qp():
    rng = np.random.default_rng(5)
    n = 4000
    a, d = rng.uniform(0.05, 1.0, n), rng.uniform(0.05, 1.0, n)
    b = rng.uniform(-0.98, 0.98, n) * np.sqrt(a * d) * (rng.uniform(size=n) > 0.1)  # some uncoupled
    lo, hi = rng.uniform(0, 0.3, (n, 2)), rng.uniform(0, 0.3, (n, 2))
    lo[:50], hi[:50] = 0.0, 0.0  # no friction at all
    v = rng.normal(0, 1e-4, (n, 2)) * rng.choice([0.01, 0.1, 1.0, 10.0], (n, 1))
    H = np.stack([np.stack([a, b], 1), np.stack([b, d], 1)], 1)
    ref = box_qp(H, v, lo, hi, 1e-4)
    ours = jax.jit(jax.vmap(Manus2().friction_solve, (0, 0, 0, 0, None)))(H, v, lo, hi, 1e-4)
    np.testing.assert_allclose(ours, ref, rtol=1e-12, atol=1e-15)
    assert np.sum(np.all((ref > -lo) & (ref < hi), 1)) > 100  # both joints held, often
    assert np.sum(np.any(np.isclose(ref, -lo) | np.isclose(ref, hi), 1)) > 100  # and sliding


def test_structure_forms_agree():
    """Matrix form, joint-tuple form and the small-move turn of the pose, against closed forms."""
    rng = np.random.default_rng(6)
    s, p = Manus2(), {"a1": A1, "a2": A2, "a3": A3}
    q, qd, dq, r = rng.uniform(-3, 3, 2), rng.normal(0, 2, 2), rng.normal(0, 1e-3, 2), rng.normal(size=2)

    @jax.jit
    def forms(q, qd, dq, r):
        pose = s.pose(tuple(q))
        H = s.inertia(q, p)
        return (
            H,
            jnp.stack(s.bias(pose, tuple(qd), p)),
            s.coriolis(q, qd, p) @ qd,
            jnp.stack(s.moved(pose, s.shift(tuple(dq)))),
            s.solve(H, r),
        )

    H, bias, cqd, turned, solved = map(np.asarray, forms(q, qd, dq, r))
    c = math.cos(q[1] - q[0])
    np.testing.assert_allclose(H, [[A1, A2 * c], [A2 * c, A3]], rtol=0, atol=1e-16)
    np.testing.assert_allclose(bias, cqd, rtol=1e-15)
    np.testing.assert_allclose(
        bias, [-A2 * math.sin(q[1] - q[0]) * qd[1] ** 2, A2 * math.sin(q[1] - q[0]) * qd[0] ** 2], rtol=1e-14
    )
    angle = q[1] + dq[1] - q[0] - dq[0]
    np.testing.assert_allclose(turned, [math.cos(angle), math.sin(angle)], rtol=0, atol=3e-16)
    np.testing.assert_allclose(solved, np.linalg.solve(H, r), rtol=1e-14)
    axis = Axis(n_joints=3)
    np.testing.assert_array_equal(
        axis.inertia(jnp.zeros(3), {"M1": 1.0, "M2": 2.0, "M3": 4.0}), np.diag([1.0, 2.0, 4.0])
    )
    held = axis.friction_solve(
        jnp.diag(jnp.array([1.0, 2.0, 4.0])), jnp.array([1e-5, -1e-3, 0.0]), jnp.full(3, 0.5), jnp.full(3, 0.5), 1e-3
    )
    np.testing.assert_allclose(held, [0.01, -0.5, 0.0])


MANY = "rigid,viscous,coulomb,stribeck,asymmetry,offset,gravity,cogging"


def test_one_period_matches_the_generic_definitions_on_random_states():
    """Ten sub-steps of `Simulator.step` against the same scheme written with the matrix forms
    (Structure.inertia, Structure.coriolis, Model.torque) and the brute-force friction step."""
    model = Model(Manus2(), MANY)
    sim = Simulator(model, actuator=None, encoder=None)
    s, p, h = model.structure, sim.params, sim.dt / sim.substeps
    rng = np.random.default_rng(8)
    n = 300
    q = np.stack([rng.uniform(-1, 1.5, n), rng.uniform(1.5, 3.5, n)], 1)
    qd = rng.normal(0, 0.3, (n, 2)) * (rng.uniform(size=(n, 2)) > 0.4)
    tau = rng.normal(0, 0.25, (n, 2))

    dyn = jax.jit(
        jax.vmap(
            lambda q, v: (s.inertia(q, p), s.coriolis(q, v, p) @ v + model.torque(q, v, jnp.zeros(2), p, only=is_load))
        )
    )
    spd = lambda v: jnp.maximum(jnp.abs(v), 1e-12)
    bounds = jax.jit(
        jax.vmap(
            lambda q, v: (
                jnp.maximum(-model.torque(q, -spd(v), jnp.zeros(2), p, only=is_dry), 0.0),
                jnp.maximum(model.torque(q, spd(v), jnp.zeros(2), p, only=is_dry), 0.0),
            )
        )
    )

    def accel(q, v):
        H, rest = map(np.asarray, dyn(q, v))
        return np.linalg.solve(H, (tau - rest)[..., None])[..., 0], H

    x, v = q.copy(), qd.copy()
    for _ in range(sim.substeps):
        xm = x + 0.5 * h * v
        vm = v + 0.5 * h * accel(x, v)[0]
        am, H = accel(xm, vm)
        vstar = v + h * am
        lo, hi = map(np.asarray, bounds(xm, v))
        f = box_qp(H, vstar, lo, hi, h)
        w = np.where((f > -lo) & (f < hi), 0.0, vstar - h * np.linalg.solve(H, f[..., None])[..., 0])
        x, v = x + 0.5 * h * (v + w), w

    def one(q, qd, tau):
        state, _ = sim.reset(q0=q, qd0=qd)
        state, _ = sim.step(state, tau)
        return state.q, state.qd

    fq, fqd = map(np.asarray, jax.jit(jax.vmap(one))(q, qd, tau))
    np.testing.assert_allclose(fq, x, rtol=0, atol=1e-15)
    np.testing.assert_allclose(fqd, v, rtol=0, atol=1e-14)
    np.testing.assert_array_equal(fqd == 0, v == 0)  # the same joints held, exactly
    assert 20 < np.sum(v == 0) < n  # stuck and sliding joints both occur


SPLIT_BATCH = """
import json, os
os.environ["XLA_FLAGS"] = "--xla_force_host_platform_device_count=2"
import equinox as eqx, jax, jax.numpy as jnp, numpy as np
jax.config.update("jax_enable_x64", True)
from manus.adaptive.impedance import Impedance
from manus.plants import Model, Simulator
from manus.plants.closed_loop import simulate, simulate_batch
from manus.plants.references import Complex
from manus.plants.structures import Manus2
plant = Simulator(Model(Manus2(), "rigid,viscous,coulomb,delay"), torque_noise=0.01)
gains = jnp.array([10.0, 25.0, 40.0, 60.0])
controllers = eqx.filter_vmap(lambda k: Impedance(k, 1.0))(gains)
keys = jax.random.split(jax.random.PRNGKey(3), 4)
batch = simulate_batch(plant, controllers, Complex(), 0.1, keys, batched=("controller",), every=7)
ones = [simulate(plant, Impedance(float(g), 1.0), Complex(), 0.1, key=k) for g, k in zip(gains, keys)]
print(json.dumps({
    "devices": len(jax.devices()), "shape": batch.q.shape,
    "vs_one_by_one": max(float(np.abs(getattr(batch, f)[i] - getattr(o, f)[::7]).max())
                         for i, o in enumerate(ones) for f in ("q", "tau", "q_true", "qd_true", "q_ref", "t")),
    "trials_differ": bool(np.abs(batch.q[0] - batch.q[3]).max() > 1e-3)}))
"""


def test_a_batch_split_over_two_devices_equals_the_trials_one_by_one():
    """With two devices (a fresh process: the flag must precede JAX's start) `simulate_batch`
    shards the trials; recording every 7th tick keeps ticks 0, 7, 14, ... of each trial."""
    out = subprocess.run(
        [sys.executable, "-c", SPLIT_BATCH],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=pathlib.Path(__file__).resolve().parents[2],
    )
    assert out.returncode == 0, out.stderr[-2000:]
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert r["devices"] == 2 and r["shape"] == [4, 15, 2]
    assert r["vs_one_by_one"] < 1e-12 and r["trials_differ"]


def test_float32_runs_in_float32_and_tracks_float64_within_an_encoder_count():
    plant64 = Simulator(Model(Manus2(), "rigid,viscous,coulomb,delay"))
    ref = simulate(plant64, Impedance(), Complex(), 0.3)
    with jax.enable_x64(False):
        traj = simulate(Simulator(Model(Manus2(), "rigid,viscous,coulomb,delay")), Impedance(), Complex(), 0.3)
    count = 2 * math.pi / 131072
    assert traj.q.dtype == np.float32 and traj.qd_true.dtype == np.float32
    assert np.abs(traj.q_true - ref.q_true).max() < 0.5 * count  # measured: 0.15 counts
    assert np.abs(traj.q - ref.q).max() <= 1.01 * count  # at most one quantization step flips
    assert np.abs(traj.qd_true - ref.qd_true).max() < 1e-3 * np.abs(ref.qd_true).max()
