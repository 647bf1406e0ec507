"""Each effect is defined once by its torque; its regressor must reproduce it exactly."""

from typing import cast

import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants.effects import VOCABULARY, Compliance, Delay, Model, is_dry, is_load, parse_effects
from manus.plants.errors import ModelError
from manus.plants.structures import Axis, Manus2

LINEAR = [name for name, cls in VOCABULARY.items() if cls().linear]


def random_state(rng, n):
    return (rng.uniform(-3, 3, n), rng.normal(0, 1, n), rng.normal(0, 5, n))


@pytest.mark.parametrize("structure", [Manus2(), Axis(n_joints=3)], ids=["manus2", "axis3"])
@pytest.mark.parametrize("name", LINEAR)
def test_regressor_times_theta_is_the_torque(structure, name):
    model = Model(structure, "rigid," + name if name != "rigid" else "rigid")
    rng = np.random.default_rng(1)
    for _ in range(5):
        q, qd, qdd = random_state(rng, structure.n_joints)
        theta = rng.normal(0, 1, len(model.names))
        params = model.unvector(jnp.asarray(theta))
        Y = model.regressor(q, qd, qdd)
        np.testing.assert_allclose(Y @ theta, model.torque(q, qd, qdd, params), rtol=1e-12, atol=1e-12)


def test_manus2_rigid_regressor_matches_the_thesis_equations():
    """Eqs. 3.2–3.3 / C.1–C.2 written out by hand (an independent reference)."""
    model = Model(Manus2(), "rigid")
    q, qd, qdd = np.array([0.3, 2.1]), np.array([0.7, -1.2]), np.array([2.0, -0.5])
    c, s = np.cos(q[1] - q[0]), np.sin(q[1] - q[0])
    expected = np.array([[qdd[0], c * qdd[1] - s * qd[1] ** 2, 0.0], [0.0, c * qdd[0] + s * qd[0] ** 2, qdd[1]]])
    np.testing.assert_allclose(model.regressor(q, qd, qdd), expected, atol=1e-14)


def test_closed_form_torques_of_friction_effects():
    s = Manus2()
    q, qd = np.array([0.1, 0.2]), np.array([0.3, -0.02])
    m = Model(s, "rigid,coulomb,stribeck:0.05,asymmetry,cogging:6")
    p = m.defaults()
    tau = np.asarray(m.torque(q, qd, np.zeros(2), p, only=lambda e: is_dry(e) or is_load(e)))
    expected = (
        np.array([0.099, -0.139])
        + np.array([0.05 * np.exp(-36), -0.07 * np.exp(-((0.02 / 0.05) ** 2))])
        + np.array([0.05 * 0.3, 0.04 * 0.02])  # asymmetry: db |q̇|
        + np.array([0.02 * np.sin(0.6) + 0.01 * np.cos(0.6), 0.015 * np.sin(1.2) - 0.01 * np.cos(1.2)])
    )
    np.testing.assert_allclose(tau, expected, rtol=1e-12)


def test_spring_and_several_cogging_orders():
    s = Manus2()
    q, qd = np.array([0.1, 0.2]), np.array([0.3, -0.02])
    m = Model(s, "spring,cogging:39+6")
    assert m.names == ("k1", "k2", "A1", "A2", "B1", "B2", "A1_2", "A2_2", "B1_2", "B2_2")
    p = dict(zip(m.names, np.arange(1.0, 11.0), strict=True))
    tau = np.asarray(m.torque(q, qd, np.zeros(2), p))
    expected = (
        np.array([1.0, 2.0]) * q
        + np.array([3.0, 4.0]) * np.sin(39 * q)
        + np.array([5.0, 6.0]) * np.cos(39 * q)
        + np.array([7.0, 8.0]) * np.sin(6 * q)
        + np.array([9.0, 10.0]) * np.cos(6 * q)
    )
    np.testing.assert_allclose(tau, expected, rtol=1e-12)
    assert parse_effects("cogging:39+6")[0].spec == "cogging:39+6"


def test_effects_own_their_rules():
    """Search spaces from the data, physical rules, joint kinds, requirements: each effect's own."""
    from manus.plants.effects import Cogging, Delay, Gravity, Span, Spring, Stribeck, Viscous

    span = Span(1e-3, 20.0, np.array([0.6, 0.3]), 2 * np.pi / 131072, np.array([1.0, 0.5]), (False, False), 6e-4)
    orders = [float(e.order) for e in Cogging().space(span)]
    assert orders[0] == np.ceil(2 * np.pi * 1.5 / 0.6) and orders[-1] == 200  # 1.5 periods over the travel
    delays = [e.seconds for e in Delay().space(span)]
    assert delays[0] == 0 and delays[1] == pytest.approx(1e-4) and delays[-1] == pytest.approx(0.1)  # 20 s: 100 ms
    vs = [float(e.vs) for e in Stribeck().space(span)]
    assert vs[0] == pytest.approx(1.2e-3) and vs[-1] == pytest.approx(1.0)  # 2x resolution .. the high speed
    assert Stribeck.requires == ("coulomb",) and Spring.brings == ("offset",)
    assert Gravity().applies(Axis(n_joints=1), (True,)) and Gravity().applies(Axis(n_joints=1), (False,)) is None
    assert Viscous().violations(Axis(n_joints=1), {"b1": -1.0}, {"b1": 0.1})
    assert not Viscous().violations(Axis(n_joints=1), {"b1": -0.1}, {"b1": 0.1})  # within two std of the bound
    assert Model(s := Manus2(), "rigid").effects[0].violations(s, {"a1": 0.3, "a2": 0.4, "a3": 0.2})
    assert Cogging(order=200.0).edge(span) and Cogging(order=39.0).edge(span) is None


def test_boundary_layer_replaces_the_sign_by_a_saturated_ramp():
    m = Model(Axis(n_joints=1), "rigid,coulomb")
    p = {"M1": 1.0, "Fc1": 2.0}
    tau = lambda v, phi: float(m.torque(np.zeros(1), np.array([v]), np.zeros(1), p, boundary=phi, only=is_dry)[0])
    assert tau(0.001, 0.0) == 2.0 and tau(0.0, 0.0) == 0.0
    assert tau(0.001, 0.01) == pytest.approx(0.2) and tau(-0.5, 0.01) == -2.0


def test_parse_specs_and_errors():
    effects = parse_effects("delay:2ms, rigid,cogging:39,stribeck:0.02")
    assert [e.name for e in effects] == ["rigid", "stribeck", "cogging", "delay"]
    assert cast(Delay, effects[-1]).seconds == pytest.approx(0.002)
    assert Model(Manus2(), effects).spec == "rigid,stribeck:0.02,cogging:39,delay:2ms"
    with pytest.raises(ModelError, match=r"unknown effect 'friction'.*vocabulary is rigid"):
        parse_effects("rigid,friction")
    with pytest.raises(ModelError, match="given twice"):
        parse_effects("rigid,viscous,viscous")
    with pytest.raises(ModelError, match="not a number"):
        parse_effects("cogging:many")
    with pytest.raises(ModelError, match="takes no argument"):
        parse_effects("viscous:3")
    for bad in ("cogging:0", "cogging:39+-6", "stribeck:-0.02", "stribeck:nan", "compliance:0hz", "compliance:inf"):
        with pytest.raises(ModelError, match="must be a positive number"):
            parse_effects(bad)
    with pytest.raises(ModelError, match="longer than 10 s"):
        parse_effects("delay:1e9ms")


def test_the_vocabulary_is_a_registry_and_each_effect_parses_its_own_argument():
    from typing import ClassVar

    from manus.plants.effects import ORDER, Cogging, Coulomb, Delay, Effect, Stribeck, parse_effect

    assert ORDER == (
        "rigid",
        "viscous",
        "coulomb",
        "stribeck",
        "smooth",
        "asymmetry",
        "offset",
        "gravity",
        "spring",
        "cogging",
        "delay",
        "compliance",
        "coupling",
    )
    assert all(VOCABULARY[name].name == name for name in ORDER)
    assert Cogging.parse("39+6") == parse_effect("cogging:39+6") and Stribeck.parse("") == Stribeck()
    assert Delay.parse("1ms/3ms").seconds == pytest.approx((1e-3, 3e-3))
    with pytest.raises(ModelError, match="effect 'coulomb' takes no argument \\(got '2'\\)"):
        Coulomb.parse("2")

    class Elsewhere(Effect):  # an effect defined outside the vocabulary is not registered in it
        name: ClassVar[str] = "elsewhere"

    assert "elsewhere" not in VOCABULARY and Elsewhere.parse("") == Elsewhere()


def test_thesis_defaults():
    d = Model(Manus2(), "rigid,viscous,coulomb").defaults()
    assert d == {"a1": 0.349, "a2": 0.241, "a3": 0.246, "b1": 0.222, "b2": 0.181, "Fc1": 0.099, "Fc2": 0.139}
    c = cast(Compliance, parse_effects("compliance")[0])
    k, b = c.shaft(jnp.asarray(1.0))  # the thesis's 1-DOF model: m = 0.1, m2 = 0.9
    assert float(k) == pytest.approx(170000, rel=0.001) and float(b) == pytest.approx(2.0, rel=0.01)


def test_a_delay_per_joint_reads_writes_and_grows_one_joint_at_a_time():
    from manus.plants.effects import Span

    (d,) = cast(tuple[Delay], parse_effects("delay:1ms/3ms"))
    assert d.seconds == pytest.approx((1e-3, 3e-3)) and parse_effects(d.spec)[0] == d
    assert d.describe() == {"delay_ms": [1.0, 3.0]}
    with pytest.raises(ModelError, match="negative"):
        parse_effects("delay:-1ms")
    with pytest.raises(ModelError, match="2 delays for 3 joints"):
        d.per_joint(3)
    span = Span(1e-3, 10.0, np.ones(2), 1e-5, np.ones(2), (False, False))
    grown = Delay(seconds=0.002).grow(span)
    grid = [cast(float, v.seconds) for v in Delay().space(span)]
    assert len(grown) == 2 * (len(grid) - 1)  # every other value, on one joint, the other at 2 ms
    assert all(sum(x != 0.002 for x in cast(tuple, g.seconds)) == 1 for g in grown)
    assert Delay(seconds=0.002).grow(Span(1e-3, 10.0, np.ones(1), 1e-5, np.ones(1), (False,))) == ()
    assert "joint 2" in cast(str, Delay(seconds=(0.0, grid[-1])).edge(span))
    assert Delay(seconds=(0.0, 0.002)).edge(span) is None  # a joint at 0 while the other is late: a value
