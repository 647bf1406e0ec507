"""The simulator against independent references: numpy RK4, energy, the sensor chain, stiction,
the shaft mode, and batch against one-by-one."""

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from adaptive.impedance import Impedance
from plants import Encoder, Model, Simulator
from plants.closed_loop import simulate, simulate_batch
from plants.references import Complex, MultiSine
from plants.structures import Axis, Manus2

A1, A2, A3, B1, B2 = 0.349, 0.241, 0.246, 0.222, 0.181


def open_loop(sim, taus, **reset):
    """Drive `sim` with the commands `taus` (T, n); true (q, qd) before each command."""
    state, _ = sim.reset(**reset)
    run = eqx.filter_jit(lambda st, u: jax.lax.scan(lambda s, x: (sim.step(s, x)[0], (s.q, s.qd, sim.measure(s))), st, u))
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
            k1 = f(x, tau); k2 = f(x + h / 2 * k1, tau); k3 = f(x + h / 2 * k2, tau); k4 = f(x + h * k3, tau)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return np.array(out)


def test_arm_matches_an_independent_rk4():
    t = np.arange(2000) * 1e-3
    taus = np.stack([0.3 * np.sin(2 * np.pi * 1.3 * t), -0.2 * np.cos(2 * np.pi * 0.7 * t)], 1)
    ref = arm_rk4([0.464, 2.409, 0.5, -0.8], taus)
    errors = []
    for substeps in (5, 20):
        sim = Simulator(Model(Manus2(), "rigid,viscous"), substeps=substeps, actuator=None, encoder=None)
        q, qd, _ = open_loop(sim, taus, qd0=jnp.array([0.5, -0.8]))
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
    out = np.asarray(sim.actuator(jnp.array([0.1234, 100.0, -100.0])))
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
    A = np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-k / m1, k / m1, -(b + b2) / m1, b2 / m1], [k / m2, -k / m2, b2 / m2, -b2 / m2]])
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
