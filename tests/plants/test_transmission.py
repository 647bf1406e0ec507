"""Transmissions θ = N q (`manus.plants.transmission`): the statement read from a URDF's
`<transmission>` elements, a recording's header and the command line gives one N; the motor-side
effects act on the actuators (against the virtual-work map written out in numpy); an identity N
changes nothing; malformed statements get a one-line error."""

import argparse
import functools
import pathlib

import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants import Model, recording
from manus.plants.errors import ManusError, ModelError, RecordingError
from manus.plants.serial import Serial
from manus.plants.structures import Manus2
from manus.plants.transmission import of_matrix, parse, stated, with_transmission
from tests.plants.test_serial import ROBOTS, urdf

EXAMPLE = pathlib.Path(__file__).resolve().parents[2] / "examples" / "dfki_double_pendulum" / "double_pendulum_a0.urdf"
DIFFERENTIAL = """
  <transmission name="wrist">
    <type>transmission_interface/DifferentialTransmission</type>
    <joint name="shoulder"><mechanicalReduction>{jr1}</mechanicalReduction></joint>
    <joint name="elbow"><mechanicalReduction>{jr2}</mechanicalReduction></joint>
    <actuator name="a"><mechanicalReduction>{ar1}</mechanicalReduction></actuator>
    <actuator name="b"><mechanicalReduction>{ar2}</mechanicalReduction></actuator>
  </transmission>
"""


def _urdf_with(tmp_path, extra: str) -> pathlib.Path:
    text = EXAMPLE.read_text()
    out = tmp_path / "with_transmission.urdf"
    out.write_text(text.replace("</robot>", extra + "</robot>"))
    return out


def _recording_file(tmp_path, header: str = "", robot: pathlib.Path | None = None) -> pathlib.Path:
    rng = np.random.default_rng(0)
    t = np.arange(200) * 0.002
    q = np.cumsum(rng.standard_normal((200, 2)) * 1e-3, axis=0)
    lines = ["# sample_rate_hz: 500"]
    if robot is not None:
        lines += ["# structure: urdf", f"# robot: {robot}"]
    if header:
        lines.append(f"# transmission: {header}")
    lines.append("t,q1,q2,tau1,tau2")
    lines += [f"{a:.6f},{b:.9f},{c:.9f},0.1,0.2" for a, (b, c) in zip(t, q, strict=True)]
    path = tmp_path / "rec.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_the_three_sources_state_the_same_n(tmp_path):
    """A differential (ros_control: θ_a = r_a (r_1 q_1 + r_2 q_2), θ_b = r_b (r_1 q_1 − r_2 q_2)) in
    the URDF, the same N in a recording's header (as a matrix) and on the command line (as
    combinations of the joints by name): one N, written out by hand."""
    path = _urdf_with(tmp_path, DIFFERENTIAL.format(jr1=1, jr2=2, ar1=3, ar2=0.5))
    expected = np.array([[3.0, 6.0], [0.5, -1.0]])
    chain = Serial.from_urdf(path)
    assert chain.transmission is not None
    np.testing.assert_array_equal(chain.transmission.matrix, expected)
    rec = recording.read(_recording_file(tmp_path, "[[3, 6], [0.5, -1]]"))  # manus2, from the header
    assert rec.structure.transmission is not None
    np.testing.assert_array_equal(rec.structure.transmission.matrix, expected)
    from manus.runs.args import load_recording

    args = _options(
        str(_recording_file(tmp_path)),
        "--robot",
        str(EXAMPLE),
        "--transmission",
        "3 shoulder + 6 elbow; 0.5*q1 - elbow",
    )
    from_cli = load_recording(args)
    assert from_cli.structure.transmission is not None
    np.testing.assert_array_equal(from_cli.structure.transmission.matrix, expected)
    # the base form identification fits and the pseudo-inertia form adaptive control uses keep it
    assert chain.base().transmission == chain.transmission == chain.pseudo().transmission
    # the statement a transmission writes reads back as itself
    t = from_cli.structure.transmission
    assert parse(t.describe(), 2) == t
    # the header replaces the URDF's: an identity statement leaves none
    rec = recording.read(_recording_file(tmp_path, "q1; q2", robot=path))
    assert rec.structure.transmission is None


def test_simple_transmissions_of_ratio_one_are_none():
    """The UR5's URDF states six simple transmissions of reduction 1: no transmission."""
    ur5 = Serial.from_urdf(urdf(ROBOTS["ur5"][0]))
    assert ur5.transmission is None


@pytest.mark.parametrize(
    "text, match",
    [
        ("q1; q1", "singular"),
        ("q1; q3 - q1", "unknown joint 'q3'"),
        ("[[1, 0], [0, 1], [1, 1]]", "must be 2×2"),
        ("m3 = q1", "actuator 3 of a structure with 2 joints"),
        ("q1; q2; q1 + q2", "actuator 3 of a structure with 2 joints"),
        ("q1 q2", "not a combination"),
        ("m2 = q2; m2 = q1 + q2", "stated twice"),
        ("[[1, 0], [0, nan]]", "not a matrix"),
        ('[[1, 0], [0, "a"]]', "not a number"),
    ],
)
def test_a_malformed_statement_is_a_one_line_error(text, match, tmp_path):
    with pytest.raises(ModelError, match=match) as e:
        parse(text, 2, where="--transmission")
    assert "\n" not in str(e.value) and str(e.value).startswith("--transmission: ")
    path = _recording_file(tmp_path, text)
    with pytest.raises(RecordingError, match=match) as e:
        recording.read(path)
    assert "\n" not in str(e.value) and str(e.value).startswith(str(path))


def test_a_urdf_transmission_on_joints_off_the_chain_or_of_an_unknown_kind_is_refused(tmp_path):
    bad = DIFFERENTIAL.replace("elbow", "nowhere").format(jr1=1, jr2=1, ar1=1, ar2=1)
    with pytest.raises(ModelError, match="not in the chain"):
        Serial.from_urdf(_urdf_with(tmp_path, bad))
    three = DIFFERENTIAL.replace("Differential", "FourBarLinkage").format(jr1=1, jr2=1, ar1=1, ar2=1)
    with pytest.raises(ModelError, match=r"simple transmission .* or a differential"):
        Serial.from_urdf(_urdf_with(tmp_path, three))


def _per_joint(params: dict, n: int, prefix: str) -> np.ndarray:
    return np.array([params[f"{prefix}{i + 1}"] for i in range(n)])


def test_motor_side_effects_act_on_the_actuators_by_virtual_work():
    """Viscous, Coulomb, offset and cogging on θ = N q, written out in numpy: τ = Nᵀ(b∘θ̇ +
    Fc∘sgn θ̇ + off + A∘sin(39 θ) + B∘cos(39 θ)); the rigid effect stays on the joints. Checked on
    MANUS-2 (the elbow motor on q2 − q1) and on the Panda with a differential wrist on joints 5, 6
    (the regressor, ∂τ/∂θ, as well)."""
    rng = np.random.default_rng(1)
    for structure, N in (
        (Manus2(), np.array([[1.0, 0.0], [-1.0, 1.0]])),
        (Serial.from_urdf(urdf(ROBOTS["panda"][0])), None),
    ):
        n = structure.n_joints
        if N is None:
            N = np.eye(n)
            N[4:6, 4:6] = [[1.0, 1.0], [1.0, -1.0]]
        s = with_transmission(structure, of_matrix(N))
        plain = Model(structure, "rigid,viscous,coulomb,offset,cogging")
        model = Model(s, "rigid,viscous,coulomb,offset,cogging")
        params = {k: float(v) for k, v in zip(model.names, rng.uniform(0.1, 1.0, len(model.names)), strict=True)}
        q, qd, qdd = rng.standard_normal((3, n))
        th, thd = N @ q, N @ qd
        pick = functools.partial(_per_joint, params, n)
        motor = pick("b") * thd + pick("Fc") * np.sign(thd) + pick("off")
        motor += pick("A") * np.sin(39 * th) + pick("B") * np.cos(39 * th)
        rigid = np.asarray(
            plain.torque(jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd), params, only=lambda e: e.inertial)
        )
        got = np.asarray(model.torque(jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd), params))
        np.testing.assert_allclose(got, rigid + N.T @ motor, rtol=1e-10, atol=1e-10)
        Y = np.asarray(model.regressor(jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd)))
        np.testing.assert_allclose(Y @ np.array([params[k] for k in model.names]), got, rtol=1e-10, atol=1e-10)


def test_an_identity_transmission_changes_nothing():
    """N = I is no transmission: the structure is the same object, its torques the same bits."""
    s = Manus2()
    assert of_matrix(np.eye(2)) is None and with_transmission(s, of_matrix(np.eye(2))) is s
    assert stated(s, "q1; q2") is s and stated(s, "[[1, 0], [0, 1]]") is s


def test_a_simulated_plant_with_an_elbow_motor_on_the_difference_is_fitted_with_its_transmission():
    """MANUS-2 in absolute angles whose elbow motor turns with q2 − q1 (`q1; q2 - q1`): its viscous
    friction simulated on the motors, fitted with the transmission stated it comes back (each
    motor's b within 2 %), fitted without it the error is many times larger."""
    import jax

    from manus.adaptive import fit
    from manus.adaptive.impedance import Impedance
    from manus.plants import Simulator
    from manus.plants.closed_loop import simulate
    from manus.plants.recording import from_trajectory
    from manus.plants.references import MultiSine

    s = stated(Manus2(), "q1; q2 - q1")
    truth = {"a1": 0.349, "a2": 0.241, "a3": 0.246, "b1": 0.3, "b2": 0.2}
    plant = Simulator(Model(s, "rigid,viscous"), truth)
    assert plant.actuator is not None
    controller = Impedance(30.0, 1.0, n_joints=2, limit=plant.actuator.limit)
    traj = simulate(plant, controller, MultiSine((0.464, 2.409), 0.3, seed=3), 8.0, key=jax.random.PRNGKey(3))
    rec = from_trajectory(traj, plant.rate_hz, "manus2", 131072, {"transmission": "q1; q2 - q1"})
    stated_fit = fit(rec, "rigid,viscous")
    for k in ("b1", "b2"):
        assert stated_fit.params[k] == pytest.approx(truth[k], rel=0.02), k
    del rec.meta["transmission"]
    plain_fit = fit(rec, "rigid,viscous")
    assert plain_fit.rel_error > 3 * stated_fit.rel_error, (plain_fit.rel_error, stated_fit.rel_error)


def _options(*argv: str) -> argparse.Namespace:
    """The options of `manus fit` (a recording and its model), as its command line reads them."""
    from manus.runs.args import add_model_options

    p = argparse.ArgumentParser()
    add_model_options(p)
    return p.parse_args([*argv, "--model", "rigid"])


def test_a_bad_transmission_on_the_command_line_is_a_manus_error(tmp_path):
    from manus.runs.args import load_recording

    args = _options(str(_recording_file(tmp_path)), "--transmission", "q2; q2")
    with pytest.raises(ManusError, match=r"--transmission: .*singular"):
        load_recording(args)


def test_a_geared_motors_smooth_friction_width_is_searched_among_the_motors_speeds():
    """MANUS-2 behind 50:1 gears (`50 q1; 50 q2`), friction Fs tanh(θ̇/w) on the motors with w =
    2.5 rad/s of the motor (0.05 rad/s of the joint): the search space of a motor-side effect is
    the actuators' (`Span.of`: speeds 50 times the joints'), so the width is found within 30 %
    and the friction levels within 10 %; a joint-side effect (a coupling) keeps the joints' span."""
    import jax

    from manus.adaptive import fit
    from manus.adaptive.identify.prepare import prepare
    from manus.adaptive.impedance import Impedance
    from manus.plants import Simulator
    from manus.plants.closed_loop import simulate
    from manus.plants.effects import Coupling, Smooth
    from manus.plants.recording import from_trajectory
    from manus.plants.references import MultiSine

    gear, statement = 50.0, "50 q1; 50 q2"
    s = stated(Manus2(), statement)
    truth = {"a1": 0.349, "a2": 0.241, "a3": 0.246, "b1": 0.2 / gear**2, "b2": 0.15 / gear**2}
    truth |= {"Fs1": 0.6 / gear, "Fs2": 0.4 / gear}
    width = 0.05 * gear
    plant = Simulator(Model(s, (*Model(s, "rigid,viscous").effects, Smooth(width=width))), truth)
    assert plant.actuator is not None
    controller = Impedance(30.0, 1.0, n_joints=2, limit=plant.actuator.limit)
    traj = simulate(plant, controller, MultiSine((0.464, 2.409), 0.3, seed=5), 8.0, key=jax.random.PRNGKey(5))
    rec = from_trajectory(traj, plant.rate_hz, "manus2", 131072, {"transmission": statement})
    rec.qd, rec.extra = None, {}
    span = prepare(rec).span()
    assert span.actuators is not None
    assert span.of(Smooth()).speed == pytest.approx(gear * span.speed)
    assert span.of(Coupling()) is span
    f = fit(rec, "rigid,viscous,smooth")
    found = f.model.get("smooth")
    assert found is not None and float(found.width) == pytest.approx(width, rel=0.3)  # pyright: ignore[reportAttributeAccessIssue]
    for k in ("Fs1", "Fs2"):
        assert f.params[k] == pytest.approx(truth[k], rel=0.1), k
