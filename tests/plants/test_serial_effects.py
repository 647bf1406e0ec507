"""A serial chain as a structure of the effect protocol: `Model(serial, ...)`, its base-parameter
form, `structure_named("urdf", ...)` and `structure: urdf` recordings (with `# robot: PATH`).
References: pinocchio's inverse dynamics (rigid, gravity included) plus the friction laws in
closed form; the regressor against the model's torque."""

from pathlib import Path
from typing import cast

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.adaptive import fit
from manus.plants import Model, Serial, SerialBase, recording, structure_named
from manus.plants.effects import Gravity
from manus.plants.errors import ModelError, RecordingError
from manus.plants.recording import Recording
from tests.plants.test_serial import PENDULUM, load, states


@pytest.fixture(scope="module")
def panda():
    return load("panda")


def test_a_model_of_a_serial_chain_is_its_rigid_torque_plus_friction_per_joint(panda):
    pin = pytest.importorskip("pinocchio")
    _, serial, model, data = panda
    m = Model(serial, "rigid,viscous,coulomb,offset")
    n = serial.n_joints
    assert m.names[: 11 * n] == serial.rigid_names and m.names[11 * n :] == (
        *(f"b{i}" for i in range(1, n + 1)),
        *(f"Fc{i}" for i in range(1, n + 1)),
        *(f"off{i}" for i in range(1, n + 1)),
    )
    rng = np.random.default_rng(7)
    p = m.defaults()
    p.update({f"b{i}": v for i, v in enumerate(rng.uniform(0.1, 1, n), 1)})
    p.update({f"Fc{i}": v for i, v in enumerate(rng.uniform(0.1, 1, n), 1)})
    p.update({f"off{i}": v for i, v in enumerate(rng.uniform(-1, 1, n), 1)})
    q, qd, qdd, _ = states(serial, 5, seed=8)
    tau = jax.jit(jax.vmap(lambda q, qd, qdd: m.torque(q, qd, qdd, p)))(q, qd, qdd)
    Y = jax.jit(jax.vmap(m.regressor))(q, qd, qdd)
    b, Fc, off = (np.array([p[f"{k}{i}"] for i in range(1, n + 1)]) for k in ("b", "Fc", "off"))
    for k in range(len(q)):
        ref = pin.rnea(model, data, q[k], qd[k], qdd[k]) + b * qd[k] + Fc * np.sign(qd[k]) + off
        np.testing.assert_allclose(tau[k], ref, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.einsum("kip,p->ki", Y, np.asarray(m.vector(p))), tau, rtol=0, atol=1e-9)


def test_the_base_form_predicts_what_the_standard_parameters_do(panda):
    _, serial, _, _ = panda
    base = serial.base()
    assert isinstance(base, SerialBase) and len(base.rigid_names) == 48 and base.serial is serial
    assert len(set(base.rigid_names)) == 48 and all(
        c in n or n.endswith("R") for n, c in zip(base.rigid_names, base.combinations, strict=True)
    )
    rng = np.random.default_rng(9)
    theta = rng.standard_normal(len(serial.rigid_names))
    p_base = dict(zip(base.rigid_names, base.values(theta), strict=True))
    p_std = dict(zip(serial.rigid_names, theta, strict=True))
    q, qd, qdd, _ = states(serial, 4, seed=10)

    def both(s, p):  # (C takes the same embedding of θ_b as H)
        return jax.jit(jax.vmap(lambda q, qd, qdd: (s.rigid_torque(q, qd, qdd, p), s.inertia(q, p))))

    for a, b in zip(both(base, p_base)(q, qd, qdd), both(serial, p_std)(q, qd, qdd), strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    # the defaults are the URDF's, reduced; a physical set has no violation, a negative-definite one has
    assert base.rigid_defaults == pytest.approx(tuple(base.values(serial.defaults)), abs=1e-12)
    assert base.violations(dict(zip(base.rigid_names, base.rigid_defaults, strict=True))) == []
    assert (
        "not positive definite"
        in base.violations({k: -v for k, v in zip(base.rigid_names, base.rigid_defaults, strict=True)})[0]
    )


def test_a_chain_and_its_forms_say_what_callers_ask_of_a_structure(panda):
    from manus.plants import Axis, Manus2, SerialPseudo

    _, serial, _, _ = panda
    base, pseudo = serial.identified_form(), serial.adaptive_form()
    assert isinstance(base, SerialBase) and isinstance(pseudo, SerialPseudo)
    assert base.identified_form() is base and pseudo.adaptive_form() is pseudo
    for s in (serial, base, pseudo):
        assert s.standard_form is serial and s.urdf_file == serial.source and s.rigid_gravity
        assert s.prismatic == serial.prismatic and s.nominal("viscous") == serial.damping
        np.testing.assert_array_equal(s.nominal_joint_inertias(), serial.nominal_joint_inertias())
    assert serial.combinations is None and base.combinations == base.written and pseudo.combinations is None
    standard = dict(zip(serial.rigid_names, serial.defaults, strict=True))
    assert serial.coordinates_of(standard) == {}
    assert tuple(pseudo.coordinates_of(standard).values()) == pytest.approx(pseudo.rigid_defaults, abs=1e-12)
    assert tuple(base.coordinates_of(standard).values()) == pytest.approx(base.rigid_defaults, abs=1e-12)
    assert pseudo.admissible() is not None and serial.admissible() is None and base.admissible() is None
    # the defaults of a structure that has nothing more to say
    axis = Axis(n_joints=2)
    assert (axis.prismatic, axis.rigid_gravity, axis.thesis_arm, axis.urdf_file, axis.nominal("viscous")) == (
        (),
        "",
        False,
        "",
        (),
    )
    assert axis.workspace_centre == (0.0, 0.0) and axis.nominal_joint_inertias() is None and axis.rigid_gains(5.0) == {}
    assert axis.slotine_li_columns(*jnp.zeros((4, 2))) is None and axis.momentum_columns(*jnp.zeros((2, 2))) is None
    assert Manus2().thesis_arm and Manus2().rigid_gains(5.0) == {"a1": 0.2, "a2": 0.2, "a3": 0.5}


def test_per_joint_gravity_is_not_an_effect_of_a_serial_chain(panda):
    _, serial, _, _ = panda
    why = Gravity().applies(serial)
    assert why and "part of rigid" in why
    assert Gravity().applies(serial.base()) == why
    from manus.plants.structures import Manus2

    assert Gravity().applies(Manus2()) is None  # MANUS-2 keeps its tilted plane


def test_structure_named_reads_a_urdf_and_checks_its_joints(tmp_path):
    path = tmp_path / "pendulum.urdf"
    path.write_text(PENDULUM)
    s = structure_named("urdf", 2, robot=path)
    assert isinstance(s, Serial) and s.joint_names == ("shoulder", "elbow") and s.source == str(path)
    with pytest.raises(ModelError, match=r"has 2 joints .shoulder, elbow., not 3"):
        structure_named("urdf", 3, robot=path)
    with pytest.raises(ModelError, match="needs the robot's URDF"):
        structure_named("urdf", 2)
    with pytest.raises(ValueError, match="'manus2', 'axis' or 'urdf'"):
        structure_named("scara", 2)


def _pendulum_recording(T: int = 400) -> Recording:
    t = np.arange(T) * 1e-3
    q = np.stack([0.3 * np.sin(2 * np.pi * t), 0.2 * np.cos(3 * np.pi * t)], 1)
    return Recording(t, q, np.zeros_like(q), meta={"sample_rate_hz": "1000"})


def test_a_urdf_recording_names_its_robot_relative_to_itself(tmp_path):
    robot = tmp_path / "robots" / "pendulum.urdf"
    robot.parent.mkdir()
    robot.write_text(PENDULUM)
    rec = _pendulum_recording()
    rec.meta.update({"structure": "urdf", "robot": str(robot)})
    for name in ("data/run.csv", "data/run.npz"):
        path = recording.write(rec, tmp_path / name)
        if path.suffix == ".csv":
            assert "# robot: ../robots/pendulum.urdf\n" in path.read_text()
        back = recording.read(path)
        assert back.structure_name == "urdf" and back.meta["robot"] == "../robots/pendulum.urdf"
        assert cast(Path, back.robot).resolve() == robot.resolve()
        assert isinstance(back.structure, Serial) and back.structure.joint_names == ("shoulder", "elbow")
        assert back.prismatic == (False, False)
        # written again elsewhere, the path follows
        again = recording.write(back, tmp_path / "other" / "deeper" / path.name)
        assert cast(Path, recording.read(again).robot).resolve() == robot.resolve()
    # --robot (read(robot=...)) makes any recording a serial chain's
    plain = recording.write(_pendulum_recording(), tmp_path / "plain.csv")
    assert recording.read(plain).structure_name == "manus2"
    forced = recording.read(plain, robot=robot)
    assert forced.structure_name == "urdf" and isinstance(forced.structure, Serial)


def test_bad_robots_are_the_recordings_error(tmp_path):
    rec = _pendulum_recording()
    rec.meta["structure"] = "urdf"
    no_robot = recording.write(rec, tmp_path / "no_robot.csv")
    with pytest.raises(RecordingError, match=r"no_robot.csv: structure urdf needs the robot's URDF: a '# robot: PATH'"):
        recording.read(no_robot)
    path = tmp_path / "missing.csv"  # a relative robot path, as a rig's own file would give it
    path.write_text(no_robot.read_text().replace("# structure: urdf\n", "# structure: urdf\n# robot: missing.urdf\n"))
    with pytest.raises(
        RecordingError,
        match=r"missing.csv: robot .*missing.urdf: no such URDF file \(the metadata's "
        r"'missing.urdf' is read relative to the recording's folder\)",
    ):
        recording.read(path)
    three = tmp_path / "three.urdf"
    three.write_text(PENDULUM.replace('<joint name="tip" type="fixed">', '<joint name="tip" type="revolute">'))
    with pytest.raises(
        RecordingError, match=r"three.urdf: the URDF's chain has 3 joints \(shoulder, elbow, tip\), not 2"
    ):
        recording.read(tmp_path / "missing.csv", robot=three)
    floating = tmp_path / "floating.urdf"
    floating.write_text(
        PENDULUM.replace('<joint name="elbow" type="revolute">', '<joint name="elbow" type="floating">')
    )
    with pytest.raises(
        RecordingError, match="joint elbow is floating; a serial chain takes revolute, continuous, prismatic"
    ):
        recording.read(tmp_path / "missing.csv", robot=floating)
    broken = tmp_path / "broken.urdf"
    broken.write_text(
        "<robot name='r'><link name='a'/><joint name='j' type='revolute'><parent link='a'/></joint></robot>"
    )
    with pytest.raises(RecordingError, match=r"broken\.urdf: not a well-formed URDF"):
        recording.read(tmp_path / "missing.csv", robot=broken)


def test_fit_refuses_per_joint_gravity_on_a_serial_chain(tmp_path):
    robot = tmp_path / "pendulum.urdf"
    robot.write_text(PENDULUM)
    rec = _pendulum_recording(2000)
    rec.meta.update({"structure": "urdf", "robot": str(robot)})
    with pytest.raises(ModelError, match="gravity: a serial chain's gravity is part of rigid"):
        fit(rec, "rigid,viscous,gravity", method="ls")


def test_the_ur5_has_a_base_form_too():
    for name in ("ur5",):
        _, serial, _, _ = load(name)
        base = serial.base()
        assert base.n_joints == serial.n_joints and base.prismatic == serial.prismatic
        np.testing.assert_allclose(base.K[:, list(base.columns)], np.eye(len(base.columns)), atol=0)
        # the base regressor spans the full one on fresh states (another seed than base_parameters')
        q, qd, qdd, _ = states(serial, 30, seed=11)
        Y = np.asarray(jax.vmap(serial.regressor)(jnp.asarray(q), qd, qdd)).reshape(-1, len(serial.rigid_names))
        Yb = np.asarray(jax.vmap(base.regressor)(jnp.asarray(q), qd, qdd)).reshape(-1, len(base.columns))
        np.testing.assert_allclose(Yb @ base.K, Y, rtol=0, atol=1e-9)
