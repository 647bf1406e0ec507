"""Serial chains from a URDF against pinocchio (the independent reference) on the Panda and the UR5
of example-robot-data, and against the closed form of a double pendulum."""

import functools
import importlib.metadata

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants.errors import ModelError
from manus.plants.serial import Serial, base_parameters

# pinocchio orders a link's ten parameters m, mx, my, mz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz; ours swap Iyy, Ixz
PIN_ORDER = np.array([0, 1, 2, 3, 4, 5, 7, 6, 8, 9])
ROBOTS = {
    "panda": ("panda_description/urdf/panda.urdf", None),
    "panda_finger": ("panda_description/urdf/panda.urdf", "panda_leftfinger"),  # a prismatic 8th joint
    "ur5": ("ur_description/urdf/ur5_robot.urdf", None),
}


def urdf(relative: str) -> str:
    try:
        share = importlib.metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    return str(share / "example-robot-data" / "robots" / relative)


def pinocchio_model(path: str, serial: Serial, armature: np.ndarray):
    """The URDF in pinocchio, the joints off our chain locked at zero (as `Serial.from_urdf` does)."""
    pin = pytest.importorskip("pinocchio")
    model = pin.buildModelFromUrdf(path)
    locked = [model.getJointId(name) for name in model.names[1:] if name not in serial.joint_names]
    if locked:
        model = pin.buildReducedModel(model, locked, np.zeros(model.nq))
    assert tuple(model.names[1:]) == serial.joint_names
    model.armature = armature
    return model, model.createData()


def states(serial: Serial, count: int, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    span = np.where(serial.prismatic, 0.04, np.pi)
    n = serial.n_joints
    return rng.uniform(-span, span, (count, n)), *rng.standard_normal((3, count, n))


@functools.cache
def load(name: str):
    """(name, our chain, pinocchio's model and data), with armatures (not in these URDFs) given to both."""
    relative, tip = ROBOTS[name]
    path = urdf(relative)
    armature = np.linspace(0.05, 0.3, Serial.from_urdf(path, tip=tip).n_joints)
    serial = Serial.from_urdf(path, tip=tip, armature=armature)
    return name, serial, *pinocchio_model(path, serial, armature)


@pytest.fixture(params=sorted(ROBOTS))
def robot(request):
    return load(request.param)


@pytest.fixture(params=["panda", "ur5"])
def arm(request):
    return load(request.param)


def test_the_chains_are_the_robots_arms():
    assert Serial.from_urdf(urdf(ROBOTS["panda"][0])).joint_names == tuple(f"panda_joint{i}" for i in range(1, 8))
    ur5 = Serial.from_urdf(urdf(ROBOTS["ur5"][0]))
    assert ur5.n_joints == 6 and not any(ur5.prismatic)
    finger = Serial.from_urdf(urdf(ROBOTS["panda"][0]), tip="panda_leftfinger")
    assert finger.n_joints == 8 and finger.prismatic[-1] and not any(finger.prismatic[:-1])


def test_inverse_dynamics_mass_matrix_and_regressor_agree_with_pinocchio(robot):
    pin = pytest.importorskip("pinocchio")
    name, serial, model, data = robot
    n, theta = serial.n_joints, serial.defaults
    # the URDF's inertial parameters, fixed links merged, as pinocchio merges them
    standard = np.concatenate([model.inertias[j + 1].toDynamicParameters()[PIN_ORDER] for j in range(n)])
    np.testing.assert_allclose(theta[: 10 * n], standard, rtol=0, atol=1e-12)
    q, qd, qdd, _ = states(serial, 20, seed=1)
    tau = jax.jit(jax.vmap(lambda q, qd, qdd: serial.rnea(q, qd, qdd, theta)))(q, qd, qdd)
    H = jax.jit(jax.vmap(lambda q: serial.mass_matrix(q, theta)))(q)
    Y = jax.jit(jax.vmap(serial.regressor))(q, qd, qdd)
    worst = {"tau": 0.0, "H": 0.0, "Y": 0.0}
    for k in range(len(q)):
        M = pin.crba(model, data, q[k])
        M = np.triu(M) + np.triu(M, 1).T
        Y_pin = pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k])
        Y_pin = Y_pin.reshape(n, n, 10)[:, :, PIN_ORDER].reshape(n, 10 * n)
        Y_pin = np.hstack([Y_pin, np.diag(qdd[k])])  # pinocchio's has no armature columns
        worst["tau"] = max(worst["tau"], np.abs(tau[k] - pin.rnea(model, data, q[k], qd[k], qdd[k])).max())
        worst["H"] = max(worst["H"], np.abs(H[k] - M).max())
        worst["Y"] = max(worst["Y"], np.abs(Y[k] - Y_pin).max())
    print(name, "max deviation from pinocchio:", worst)
    assert max(worst.values()) < 1e-9
    np.testing.assert_allclose(np.einsum("kij,j->ki", Y, theta), tau, rtol=0, atol=1e-9)


def test_coriolis_is_skew_symmetric_and_slotine_li_regressor_is_exact(arm):
    pin = pytest.importorskip("pinocchio")
    _, serial, model, data = arm
    theta = serial.defaults
    p = dict(zip(serial.rigid_names, theta, strict=True))
    q, qd, qd_r, qdd_r = (jnp.asarray(x) for x in states(serial, 3, seed=2))

    def check(q, qd, qd_r, qdd_r):
        H = serial.inertia(q, p)
        Hdot = jax.jvp(lambda q: serial.mass_matrix(q, theta), (q,), (qd,))[1]
        C = serial.coriolis(q, qd, p)
        g = serial.rnea(q, 0 * q, 0 * q, theta)
        Y = serial.slotine_li_regressor(q, qd, qd_r, qdd_r)
        return Hdot - 2 * C, H @ qdd_r + C @ qd_r + g, Y @ theta, H @ qdd_r + C @ qd + g

    skew, sl, Y_theta, rigid = jax.jit(jax.vmap(check))(q, qd, qd_r, qdd_r)
    np.testing.assert_allclose(skew, -np.swapaxes(skew, 1, 2), rtol=0, atol=1e-9)
    np.testing.assert_allclose(Y_theta, sl, rtol=0, atol=1e-9)
    # with q̇_r = q̇ the Slotine–Li torque is the inverse dynamics
    np.testing.assert_allclose(
        rigid, [pin.rnea(model, data, *np.asarray(x)) for x in zip(q, qd, qdd_r, strict=True)], rtol=0, atol=1e-9
    )


def test_base_parameters_span_the_regressor(robot):
    pin = pytest.importorskip("pinocchio")
    name, serial, model, data = robot
    base = base_parameters(serial)
    print(name, "base parameters:", len(base.columns), "of", len(serial.rigid_names))
    assert len(base.columns) == {"panda": 48, "panda_finger": 53, "ur5": 40}[name]  # armatures included
    q, qd, qdd, _ = states(serial, 60, seed=3)
    Y = np.asarray(jax.jit(jax.vmap(serial.regressor))(q, qd, qdd)).reshape(-1, len(serial.rigid_names))
    # pinocchio's regressor, with the armature columns, has the same numerical rank
    pins = [
        np.hstack([pin.computeJointTorqueRegressor(model, data, *x), np.diag(x[2])])
        for x in zip(q, qd, qdd, strict=True)
    ]
    assert len(base.columns) == np.linalg.matrix_rank(Y) == np.linalg.matrix_rank(np.vstack(pins))
    rng = np.random.default_rng(4)
    theta = rng.standard_normal(Y.shape[1])  # any parameters: the map holds for all of them
    np.testing.assert_allclose(base.regressor(Y) @ base.values(theta), Y @ theta, rtol=0, atol=1e-9)
    assert len(base.names) == len(base.columns) and len(set(base.names)) == len(base.names)


# -- the double pendulum in closed form ------------------------------------------------------------

L1, LC1, LC2, L2, M1, M2, MT, I1, I2 = 0.5, 0.2, 0.25, 0.4, 1.3, 0.8, 0.2, 0.03, 0.02
PENDULUM = f"""<?xml version="1.0"?>
<robot name="double_pendulum">
  <link name="base"/>
  <joint name="shoulder" type="revolute">
    <parent link="base"/><child link="upper"/><axis xyz="0 1 0"/>
  </joint>
  <link name="upper">
    <inertial><origin xyz="0 0 {-LC1}"/><mass value="{M1}"/>
      <inertia ixx="0.011" ixy="0" ixz="0" iyy="{I1}" iyz="0" izz="0.007"/></inertial>
  </link>
  <joint name="elbow" type="revolute">
    <origin xyz="0 0 {-L1}"/><parent link="upper"/><child link="lower"/><axis xyz="0 1 0"/>
    <dynamics damping="0.1" armature="0.004"/>
  </joint>
  <link name="lower">
    <inertial><origin xyz="0 0 {-LC2}"/><mass value="{M2}"/>
      <inertia ixx="0.005" ixy="0" ixz="0" iyy="{I2}" iyz="0" izz="0.003"/></inertial>
  </link>
  <joint name="tip" type="fixed">
    <origin xyz="0 0 {-L2}" rpy="0.3 0.2 0.1"/><parent link="lower"/><child link="weight"/>
  </joint>
  <link name="weight"><inertial><mass value="{MT}"/>
    <inertia ixx="0" iyy="0" izz="0" ixy="0" ixz="0" iyz="0"/></inertial></link>
</robot>
"""


def pendulum_closed_form(q, qd, qdd, g=9.81):
    """Angles from the downward vertical, the elbow's relative to the upper link; the point mass MT at
    the lower link's end folds into its mass, centre of mass and inertia."""
    m2 = M2 + MT
    lc2 = (M2 * LC2 + MT * L2) / m2
    i2 = I2 + M2 * (lc2 - LC2) ** 2 + MT * (L2 - lc2) ** 2
    c2, s2 = np.cos(q[1]), np.sin(q[1])
    H = np.array(
        [
            [I1 + i2 + M1 * LC1**2 + m2 * (L1**2 + lc2**2 + 2 * L1 * lc2 * c2), i2 + m2 * (lc2**2 + L1 * lc2 * c2)],
            [i2 + m2 * (lc2**2 + L1 * lc2 * c2), i2 + m2 * lc2**2],
        ]
    )
    h = m2 * L1 * lc2 * s2
    coriolis = np.array([-h * (2 * qd[0] * qd[1] + qd[1] ** 2), h * qd[0] ** 2])
    gravity = g * np.array(
        [(M1 * LC1 + m2 * L1) * np.sin(q[0]) + m2 * lc2 * np.sin(q[0] + q[1]), m2 * lc2 * np.sin(q[0] + q[1])]
    )
    return H, H @ qdd + coriolis + gravity


def test_double_pendulum_matches_its_closed_form(tmp_path):
    path = tmp_path / "pendulum.urdf"
    path.write_text(PENDULUM)
    serial = Serial.from_urdf(path)
    assert serial.joint_names == ("shoulder", "elbow") and serial.rigid_defaults[-2:] == (0.0, 0.004)
    theta = np.append(serial.defaults[:-1], 0.0)  # the closed form has no armature
    q, qd, qdd, _ = states(serial, 5, seed=5)
    tau = jax.jit(jax.vmap(lambda q, qd, qdd: serial.rnea(q, qd, qdd, theta)))(q, qd, qdd)
    H = jax.jit(jax.vmap(lambda q: serial.mass_matrix(q, theta)))(q)
    for k in range(len(q)):
        H_ref, tau_ref = pendulum_closed_form(q[k], qd[k], qdd[k])
        np.testing.assert_allclose(H[k], H_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(tau[k], tau_ref, rtol=0, atol=1e-12)


def test_refuses_what_is_not_a_serial_chain(tmp_path):
    path = tmp_path / "floating.urdf"
    path.write_text(
        '<robot name="r"><link name="a"/><link name="b"/><joint name="j" type="floating">'
        '<parent link="a"/><child link="b"/></joint></robot>'
    )
    with pytest.raises(ModelError, match="floating"):
        Serial.from_urdf(path)
    path.write_text(
        '<robot name="r"><link name="a"/><link name="b"/><link name="c"/>'
        '<joint name="j1" type="revolute"><parent link="a"/><child link="b"/></joint>'
        '<joint name="j2" type="revolute"><parent link="a"/><child link="c"/></joint></robot>'
    )
    with pytest.raises(ModelError, match="branches into j1, j2: name the tip link"):
        Serial.from_urdf(path)
    assert Serial.from_urdf(path, tip="c").joint_names == ("j2",)
    with pytest.raises(ModelError, match="no such URDF file"):
        Serial.from_urdf(tmp_path / "missing.urdf")
