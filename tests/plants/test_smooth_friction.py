"""Smooth friction (`smooth`: Fs tanh(q̇/w)): its torque and columns against numpy, its spec, its
width's search space and edge, its rule; and the simulator integrating it as an ordinary smooth
torque (no stiction), against closed forms and an independent integrator (pinocchio's ABA)."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants.effects import VOCABULARY, Coulomb, Model, Smooth, Span, Stribeck, is_dry, is_load, parse_effects
from manus.plants.errors import ModelError
from manus.plants.structures import Axis, Manus2


def test_torque_and_columns_are_fs_tanh_of_speed_over_width():
    s = Manus2()
    e = Smooth(width=0.07)
    qd = np.array([[0.0, -0.0], [0.03, -0.2], [-0.5, 2.0], [1e-4, -1e-4]])
    p = {"Fs1": 0.3, "Fs2": 0.11}
    for v in qd:
        tau = np.asarray(e.torque(s, jnp.zeros(2), jnp.asarray(v), jnp.zeros(2), p))
        np.testing.assert_allclose(tau, [0.3 * math.tanh(v[0] / 0.07), 0.11 * math.tanh(v[1] / 0.07)], rtol=1e-14)
    Y = np.asarray(jax.vmap(Model(s, (e,)).regressor)(jnp.zeros((4, 2)), jnp.asarray(qd), jnp.zeros((4, 2))))
    np.testing.assert_allclose(Y[:, 0, 0], np.tanh(qd[:, 0] / 0.07), rtol=1e-14)
    np.testing.assert_allclose(Y[:, 1, 1], np.tanh(qd[:, 1] / 0.07), rtol=1e-14)
    assert np.all(Y[:, 0, 1] == 0) and np.all(Y[:, 1, 0] == 0)  # one level per joint
    # the boundary layer of adaptive control is the sign's; the tanh law is smooth already
    v = jnp.array([0.01, -0.02])
    assert np.array_equal(e.torque(s, 0 * v, v, 0 * v, p, boundary=0.5), e.torque(s, 0 * v, v, 0 * v, p))


def test_its_limit_is_coulombs_sign_and_it_is_not_dry():
    s = Axis(n_joints=1)
    v = jnp.array([0.3])
    p = {"Fs1": 2.0, "Fc1": 2.0}
    narrow = float(Smooth(width=1e-9).torque(s, 0 * v, v, 0 * v, p)[0])
    assert narrow == pytest.approx(float(Coulomb().torque(s, 0 * v, v, 0 * v, p)[0]), rel=1e-15)
    assert not Smooth.dry and is_load(Smooth()) and not is_dry(Smooth()) and Smooth.linear
    assert Smooth.replaces == ("coulomb",) and Smooth.requires == ("coulomb",) and Smooth.evidence == "velocity"


def test_spec_parse_describe_and_its_place_in_the_vocabulary():
    order = list(VOCABULARY)
    assert order.index("smooth") == order.index("stribeck") + 1
    (e,) = parse_effects("smooth:0.05")
    assert isinstance(e, Smooth) and float(e.width) == 0.05 and e.spec == "smooth:0.05"
    assert parse_effects(e.spec)[0].spec == e.spec and e.describe() == {"width": 0.05}
    (default,) = parse_effects("smooth")
    assert isinstance(default, Smooth) and float(default.width) == float(Smooth().width)
    m = Model(Manus2(), "rigid,viscous,smooth:0.2")
    assert m.names[-2:] == ("Fs1", "Fs2") and m.spec == "rigid,viscous,smooth:0.2"
    for bad in ("smooth:0", "smooth:-0.1", "smooth:nan", "smooth:inf"):
        with pytest.raises(ModelError, match=r"smooth friction width: .* must be a positive number"):
            parse_effects(bad)
    with pytest.raises(ModelError, match="not a number"):
        parse_effects("smooth:wide")


def _span(resolution=1e-3, speed=(0.8, 0.6)):
    n = len(speed)
    return Span(1e-3, 10.0, np.ones(n), 1e-5, np.array(speed), (False,) * n, resolution, 16.0, np.array(speed) / 3)


def test_the_width_is_searched_from_the_resolution_to_half_the_high_speed():
    grid = list(Smooth().space(_span()))
    w = np.array([float(x.width) for x in grid])
    assert w[0] == pytest.approx(2e-3) and w[-1] == pytest.approx(0.4)  # 2 × resolution .. TOP × max speed
    ratio = w[1:] / w[:-1]
    np.testing.assert_allclose(ratio, ratio[0], rtol=1e-9)  # geometric
    assert ratio[0] <= Smooth.STEP + 1e-9 and len(grid) <= Smooth.MAX_GRID
    # the edges: the lower one is Coulomb's sign, the upper one the widest law tried
    low = grid[0].edge(_span())
    assert low is not None and "lower edge" in low and "Coulomb's sign" in low
    up = grid[-1].edge(_span())
    assert up is not None and "upper edge" in up
    assert grid[len(grid) // 2].edge(_span()) is None
    # a motion too slow for any width the data resolve: nothing to search
    assert not Smooth().space(_span(resolution=0.1, speed=(0.3,)))


def test_a_negative_level_breaks_its_rule():
    s = Manus2()
    v = Smooth().violations(s, {"Fs1": -0.2, "Fs2": 0.1}, {"Fs1": 0.01, "Fs2": 0.01})
    assert len(v) == 1 and v[0].startswith("Fs1 = -0.2") and "friction opposes motion: Fs ≥ 0" in v[0]
    assert Smooth().violations(s, {"Fs1": -0.01, "Fs2": 0.1}, {"Fs1": 0.02, "Fs2": 0.01}) == []  # within 2 σ


# -- the simulator ---------------------------------------------------------------------------------


def _axis_run(effects: str, params: dict, u: float, periods: int, substeps: int = 10):
    from manus.plants.simulator import Simulator

    sim = Simulator(Model(Axis(n_joints=1), effects), params, substeps=substeps, actuator=None, encoder=None)
    state, _ = sim.reset()

    def tick(state, _):
        state, _ = sim.step(state, jnp.array([u]))
        return state, (state.q[0], state.qd[0])

    q, qd = jax.lax.scan(tick, state, None, length=periods)[1]
    return np.asarray(q), np.asarray(qd)


def test_under_a_torque_below_its_level_a_smooth_law_creeps_where_coulomb_sticks():
    """No stiction: M v̇ = u − Fs tanh(v/w) settles at v∞ = w atanh(u/Fs), however small u; the
    Coulomb law with the same level holds the axis exactly at rest."""
    M, Fs, w, u = 0.5, 2.0, 0.05, 1.2
    _, v = _axis_run("rigid,smooth:0.05", {"M1": M, "Fs1": Fs}, u, 3000)
    assert v[-1] == pytest.approx(w * math.atanh(u / Fs), rel=1e-9)
    q, v = _axis_run("rigid,coulomb", {"M1": M, "Fc1": Fs}, u, 300)
    assert np.all(v == 0) and np.all(q == 0)


def test_the_simulated_axis_follows_an_independent_integrator():
    """M q̈ = u − b q̇ − Fs tanh(q̇/w) from rest, against scipy's adaptive Runge–Kutta (DOP853)."""
    from scipy.integrate import solve_ivp

    M, b, Fs, w, u = 0.5, 1.5, 2.0, 0.02, 2.6
    q, v = _axis_run("rigid,viscous,smooth:0.02", {"M1": M, "b1": b, "Fs1": Fs}, u, 400)
    t = np.arange(1, 401) * 1e-3
    ref = solve_ivp(
        lambda _, x: [x[1], (u - b * x[1] - Fs * np.tanh(x[1] / w)) / M],
        (0, t[-1]),
        [0.0, 0.0],
        method="DOP853",
        t_eval=t,
        rtol=1e-12,
        atol=1e-14,
    )
    assert v[-1] > 10 * w  # it moved well past the width
    print(f"axis: |q − q_ref| ≤ {np.abs(q - ref.y[0]).max():.2g} m, |v − v_ref| ≤ {np.abs(v - ref.y[1]).max():.2g} m/s")
    np.testing.assert_allclose(q, ref.y[0], atol=5e-7)  # (Störmer–Verlet sub-steps of 0.1 ms: second order)
    np.testing.assert_allclose(v, ref.y[1], atol=3e-6)


def test_the_simulated_panda_with_smooth_friction_follows_pinocchios_forward_dynamics():
    """A serial chain (`manus.plants.serial_sim`'s simulator): rigid, viscous and smooth friction
    under a constant torque, against RK4 on pinocchio's ABA with the tanh law in its torque."""
    pin = pytest.importorskip("pinocchio")
    from tests.plants.test_serial import load
    from tests.plants.test_serial_sim import _simulate, rk4

    _, serial, model, data = load("panda")
    n = serial.n_joints
    b, Fs, w = np.linspace(0.5, 0.2, n), np.linspace(0.8, 0.3, n), 0.05
    q0 = np.array([0.1, -0.4, 0.2, -2.0, 0.3, 1.6, 0.7])
    tau = np.array(pin.rnea(model, data, q0, np.zeros(n), np.zeros(n))) + np.linspace(2.0, -1.0, n)
    m = Model(serial, f"rigid,viscous,smooth:{w}")
    params = {**{f"b{i + 1}": b[i] for i in range(n)}, **{f"Fs{i + 1}": Fs[i] for i in range(n)}}
    [(q, qd)] = _simulate(m, params, q0, [tau], periods=200)

    def f(x):
        return np.r_[x[n:], pin.aba(model, data, x[:n], x[n:], tau - b * x[n:] - Fs * np.tanh(x[n:] / w))]

    ref = rk4(f, np.r_[q0, np.zeros(n)])
    moved = np.abs(ref[-1, :n] - q0).max()
    err_q, err_v = np.abs(q - ref[:, :n]).max(), np.abs(qd - ref[:, n:]).max()
    print(f"Panda with smooth friction: moved {moved:.3g} rad, |q − q_ABA| ≤ {err_q:.2g}, |q̇ − q̇_ABA| ≤ {err_v:.2g}")
    assert moved > 0.03 and err_q < 1e-6 * max(1.0, moved) and err_v < 1e-5


def test_stribeck_is_not_offered_on_smooth_friction():
    """Stribeck's hump sits on Coulomb's sign (`requires`); smooth friction does not bring it."""
    assert Stribeck.requires == ("coulomb",) and "smooth" not in Stribeck.requires
