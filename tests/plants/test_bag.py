"""ROS 2 bags (`manus.plants.bag`): bags written with rosbags' own Writer, in sqlite3 and MCAP
storage, from known arrays, read back to the sample; the topic, joint and stamp rules, a command
topic held to the state stamps, and the refusals (one line each)."""

import sys

import numpy as np
import pytest
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.stores.ros2_humble import builtin_interfaces__msg__Time as Time
from rosbags.typesys.stores.ros2_humble import sensor_msgs__msg__JointState as JointState
from rosbags.typesys.stores.ros2_humble import std_msgs__msg__Float64MultiArray as Float64MultiArray
from rosbags.typesys.stores.ros2_humble import std_msgs__msg__Header as Header
from rosbags.typesys.stores.ros2_humble import std_msgs__msg__MultiArrayLayout as MultiArrayLayout

from manus.plants.bag import NEEDS_EXTRA, is_bag, read_bag
from manus.plants.errors import RecordingError

STORE = get_typestore(Stores.ROS2_HUMBLE)
STORAGES = {"sqlite3": (StoragePlugin.SQLITE3, ".db3"), "mcap": (StoragePlugin.MCAP, ".mcap")}
START = 1_700_000_000_123_456_789  # ns: an epoch stamp, beyond a float's nanosecond precision
LATENCY = 250_000  # ns from a message's stamp to its receipt by the recorder
NAMES = ("shoulder", "elbow")


def _source(n=2000, names=NAMES):
    """Known samples at 1 kHz: stamps [ns], positions, velocities, efforts (time, joint)."""
    stamps = START + np.arange(n, dtype=np.int64) * 1_000_000
    s = np.arange(n)[:, None] * 1e-3
    k = np.arange(1, len(names) + 1)
    return stamps, np.sin(2 * np.pi * k * s) + k, 2 * np.pi * k * np.cos(2 * np.pi * k * s), 0.3 * k * np.sin(s) - 0.1


def _state(names, stamp, q=(), v=(), e=()):
    t = Time(sec=int(stamp) // 1_000_000_000, nanosec=int(stamp) % 1_000_000_000)
    return JointState(
        header=Header(stamp=t, frame_id=""),
        name=list(names),
        position=np.array(q, float),
        velocity=np.array(v, float),
        effort=np.array(e, float),
    )


def _array(values):
    return Float64MultiArray(layout=MultiArrayLayout(dim=[], data_offset=0), data=np.asarray(values, float))


def _write(path, storage, topics):
    """A bag at `path`: `topics` maps a topic to (its type, [(receive time ns, message), ...])."""
    with Writer(path, version=9, storage_plugin=STORAGES[storage][0]) as w:
        conns = {topic: w.add_connection(topic, kind, typestore=STORE) for topic, (kind, _) in topics.items()}
        for topic, (kind, messages) in topics.items():
            for received, msg in messages:
                w.write(conns[topic], int(received), STORE.serialize_cdr(msg, kind))
    return path


def _states(stamps, q, v=None, e=None, names=NAMES, received=None):
    received = stamps + LATENCY if received is None else received
    return [
        (received[i], _state(names, stamps[i], q[i], () if v is None else v[i], () if e is None else e[i]))
        for i in range(len(stamps))
    ]


def _refused(match, *args, **kwargs):
    with pytest.raises(RecordingError, match=match) as e:
        read_bag(*args, **kwargs)
    assert "\n" not in str(e.value)
    return str(e.value)


@pytest.mark.parametrize("storage", STORAGES)
def test_columns_read_back_equal_the_source(tmp_path, storage):
    """2 joints, 2000 samples at 1 kHz: positions, efforts and velocities exactly, `t` to 1 ns
    from the epoch stamps; a message logged out of stamp order comes back in order, two equal
    stamps both kept in the order logged; the directory and its storage file read alike."""
    stamps, q, v, e = _source()
    received = stamps + LATENCY
    stamps[1500] = stamps[1499]  # a repeated stamp: kept, for the time-base repair
    messages = _states(stamps, q, v, e, received=received)
    messages[700], messages[701] = messages[701], messages[700]  # logged out of order
    messages[700] = (messages[701][0] - 1, messages[700][1])  # (received in the order written)
    bag = _write(tmp_path / "run", storage, {"/joint_states": (JointState.__msgtype__, messages)})
    storage_file = next(bag.glob("*" + STORAGES[storage][1]))
    for path in (bag, storage_file):
        assert is_bag(path)
        cols, meta, notes = read_bag(path)
        assert notes == []
        assert list(cols) == ["t", "q1", "q2", "tau1", "tau2", "v1", "v2"]
        np.testing.assert_array_equal(np.round(cols["t"] * 1e9).astype(np.int64), stamps - START)
        for i in range(2):
            np.testing.assert_array_equal(cols[f"q{i + 1}"], q[:, i])
            np.testing.assert_array_equal(cols[f"tau{i + 1}"], e[:, i])
            np.testing.assert_array_equal(cols[f"v{i + 1}"], v[:, i])
        assert meta == {
            "source": "ROS 2 bag, /joint_states (sensor_msgs/msg/JointState)",
            "joint_names": "shoulder,elbow",
            "torque_from": "/joint_states effort",
            "time_from": "header stamps",
            "start_stamp_ns": str(START),
        }


def test_joints_chosen_and_ordered_by_name(tmp_path):
    """Joints are found by name in each message (a publisher may reorder its names), in the order
    asked; a name the topic lacks is refused naming the ones it has."""
    names = ("shoulder", "elbow", "gripper")
    stamps, q, v, e = _source(200, names)
    messages = _states(stamps, q, v, e, names=names)
    for i in range(1, 200, 2):  # every other message names its joints backwards
        r = messages[i][1]
        messages[i] = (
            messages[i][0],
            _state(names[::-1], stamps[i], r.position[::-1], r.velocity[::-1], r.effort[::-1]),
        )
    bag = _write(tmp_path / "run", "sqlite3", {"/joint_states": (JointState.__msgtype__, messages)})
    cols, meta, _ = read_bag(bag, joints=["gripper", "shoulder"])
    assert meta["joint_names"] == "gripper,shoulder"
    assert list(cols) == ["t", "q1", "q2", "tau1", "tau2", "v1", "v2"]
    for col, j in ((1, 2), (2, 0)):
        np.testing.assert_array_equal(cols[f"q{col}"], q[:, j])
        np.testing.assert_array_equal(cols[f"tau{col}"], e[:, j])
        np.testing.assert_array_equal(cols[f"v{col}"], v[:, j])
    cols, meta, _ = read_bag(bag)  # the first message's names, in its order
    assert meta["joint_names"] == "shoulder,elbow,gripper"
    np.testing.assert_array_equal(np.column_stack([cols["q1"], cols["q2"], cols["q3"]]), q)
    _refused(
        r"no joint wrist on /joint_states: its joints are shoulder, elbow, gripper", bag, joints=["wrist", "elbow"]
    )


def test_the_only_joint_state_topic_by_default(tmp_path):
    """The bag's one JointState topic is read whatever else it holds; two are refused naming
    both and `--topic`; none, or a topic not in the bag, is refused naming what it has."""
    stamps, q, v, e = _source(50)
    states = _states(stamps, q, v, e)
    other = [(s, _array([1.0, 2.0])) for s in stamps]
    bag = _write(
        tmp_path / "one",
        "mcap",
        {"/joint_states": (JointState.__msgtype__, states), "/cmd": (Float64MultiArray.__msgtype__, other)},
    )
    cols, meta, _ = read_bag(bag)
    assert meta["source"] == "ROS 2 bag, /joint_states (sensor_msgs/msg/JointState)"
    np.testing.assert_array_equal(cols["q1"], q[:, 0])
    _refused(
        r"no topic /nope: the bag has /cmd \(std_msgs/msg/Float64MultiArray\), /joint_states \(sensor", bag, "/nope"
    )
    _refused(r"topic /cmd holds std_msgs/msg/Float64MultiArray, not sensor_msgs/msg/JointState", bag, "/cmd")

    moved = _states(stamps, q + 5, v, e)
    two = _write(
        tmp_path / "two",
        "sqlite3",
        {"/arm/joint_states": (JointState.__msgtype__, states), "/joint_states": (JointState.__msgtype__, moved)},
    )
    _refused(r"several sensor_msgs/msg/JointState topics \(/arm/joint_states, /joint_states\): .*--topic", two)
    cols, meta, _ = read_bag(two, topic="/joint_states")
    np.testing.assert_array_equal(cols["q1"], q[:, 0] + 5)
    assert meta["source"].startswith("ROS 2 bag, /joint_states ")

    none = _write(tmp_path / "none", "sqlite3", {"/cmd": (Float64MultiArray.__msgtype__, other)})
    _refused(r"no sensor_msgs/msg/JointState topic: the bag has /cmd \(std_msgs/msg/Float64MultiArray\)$", none)
    empty = _write(tmp_path / "empty", "mcap", {"/joint_states": (JointState.__msgtype__, [])})
    _refused(r"no messages on /joint_states$", empty)


def test_unset_header_stamps_give_the_receive_times(tmp_path):
    """Header stamps all zero (a publisher that leaves them unset): the bag's receive times, with
    a note; one unset stamp among set ones: that message dropped, with a note."""
    stamps, q, v, e = _source(300)
    received = stamps + 37 * np.arange(300)  # the recorder's clock, not the stamps
    bag = _write(
        tmp_path / "unset",
        "sqlite3",
        {"/joint_states": (JointState.__msgtype__, _states(np.zeros_like(stamps), q, v, e, received=received))},
    )
    cols, meta, notes = read_bag(bag)
    np.testing.assert_array_equal(np.round(cols["t"] * 1e9).astype(np.int64), received - received[0])
    assert meta["start_stamp_ns"] == str(received[0]) and meta["time_from"] == "receive times"
    assert notes == ["header stamps unset on /joint_states: the bag's receive times used"]
    np.testing.assert_array_equal(cols["q2"], q[:, 1])

    some = stamps.copy()
    some[10] = 0
    bag = _write(tmp_path / "some", "mcap", {"/joint_states": (JointState.__msgtype__, _states(some, q, v, e))})
    cols, meta, notes = read_bag(bag)
    assert meta["time_from"] == "header stamps" and len(cols["t"]) == 299
    np.testing.assert_array_equal(cols["q1"], np.delete(q[:, 0], 10))
    assert notes == ["1 messages on /joint_states with unset header stamps (zero) dropped"]


@pytest.mark.parametrize("storage", STORAGES)
def test_a_command_topic_held_to_the_state_stamps(tmp_path, storage):
    """Float64MultiArray commands at 250 Hz, received at (3 + 4j) ms: state sample k (stamped k ms,
    efforts left empty) holds command (k - 3) // 4, the one at its own stamp included; the
    samples before the first command are dropped, with a note."""
    n = 400
    stamps, q, v, _ = _source(n)
    commands = np.column_stack([np.arange(100) * 0.5, -np.arange(100) - 0.25])
    received = START + (3 + 4 * np.arange(100, dtype=np.int64)) * 1_000_000
    bag = _write(
        tmp_path / "cmd",
        storage,
        {
            "/joint_states": (JointState.__msgtype__, _states(stamps, q, v)),
            "/effort_controller/commands": (
                Float64MultiArray.__msgtype__,
                [(received[j], _array(commands[j])) for j in range(100)],
            ),
        },
    )
    _refused(r"the torque is missing: no efforts on /joint_states .*--command-topic", bag)
    cols, meta, notes = read_bag(bag, command_topic="/effort_controller/commands")
    k = np.arange(3, n)
    np.testing.assert_array_equal(np.round(cols["t"] * 1e9).astype(np.int64), stamps[k] - stamps[3])
    assert meta["start_stamp_ns"] == str(stamps[3])
    np.testing.assert_array_equal(cols["q1"], q[k, 0])
    np.testing.assert_array_equal(cols["tau1"], commands[(k - 3) // 4, 0])
    np.testing.assert_array_equal(cols["tau2"], commands[(k - 3) // 4, 1])
    assert meta["torque_from"] == (
        "/effort_controller/commands (std_msgs/msg/Float64MultiArray data), the latest at each state stamp"
    )
    assert "3 samples on /joint_states before the first command on /effort_controller/commands dropped" in notes
    assert any("receive times of /effort_controller/commands are matched to the header stamps" in m for m in notes)
    _refused(r"no command topic /cmd: the bag has", bag, command_topic="/cmd")


def test_a_joint_state_command_topic_by_name(tmp_path):
    """A JointState command topic: its efforts by joint name, at its header stamps."""
    stamps, q, v, e = _source(100)
    cmd_stamps = stamps[::10] + 500_000  # half-way between samples
    cmds = [
        (s + LATENCY, _state(NAMES[::-1], s, e=(-j, j))) for j, s in enumerate(cmd_stamps)
    ]  # (elbow, shoulder) = (-j, j)
    bag = _write(
        tmp_path / "js",
        "sqlite3",
        {"/joint_states": (JointState.__msgtype__, _states(stamps, q, v, e)), "/cmd": (JointState.__msgtype__, cmds)},
    )
    _refused(r"several sensor_msgs/msg/JointState topics", bag, command_topic="/cmd")
    cols, meta, notes = read_bag(bag, topic="/joint_states", command_topic="/cmd")
    k = np.arange(1, 100)  # sample 0 is before the first command
    np.testing.assert_array_equal(cols["tau1"], (k - 1) // 10)
    np.testing.assert_array_equal(cols["tau2"], -((k - 1) // 10))
    assert meta["torque_from"] == "/cmd (sensor_msgs/msg/JointState effort), the latest at each state stamp"
    assert notes == ["1 samples on /joint_states before the first command on /cmd dropped"]


def test_messages_without_efforts_skipped_and_counted(tmp_path):
    """A publisher that leaves the efforts (or velocities) empty in some messages: those skipped
    for want of a torque, counted in a note; velocities missing in some left out, with a note."""
    stamps, q, v, e = _source(2000)
    messages = _states(stamps, q, v, e)
    empty = np.arange(0, 2000, 10)
    for i in empty:
        messages[i] = (messages[i][0], _state(NAMES, stamps[i], q[i], v[i]))
    messages[5] = (messages[5][0], _state(NAMES, stamps[5], q[5], (), e[5]))  # no velocity
    bag = _write(tmp_path / "eff", "mcap", {"/joint_states": (JointState.__msgtype__, messages)})
    cols, _, notes = read_bag(bag)
    keep = np.setdiff1d(np.arange(2000), empty)
    assert len(cols["t"]) == 1800
    np.testing.assert_array_equal(cols["tau2"], e[keep, 1])
    np.testing.assert_array_equal(cols["q1"], q[keep, 0])
    assert "v1" not in cols
    assert notes == [
        "200 of 2000 messages on /joint_states skipped: fewer efforts than names (left empty by the publisher)",
        "velocities left out: 1 of 1800 samples on /joint_states lack them",
    ]


def test_what_is_no_bag(tmp_path):
    """A directory without metadata.yaml, or another file, is no bag; reading one is refused."""
    plain = tmp_path / "logs"
    plain.mkdir()
    (plain / "run.csv").write_text("t,q1,tau1\n0,0,0\n")
    assert not is_bag(plain) and not is_bag(plain / "run.csv") and not is_bag(tmp_path / "missing")
    _refused(r"logs: a directory without metadata.yaml: not a ROS 2 bag$", plain)
    _refused(r"run.csv: not a ROS 2 bag", plain / "run.csv")
    _refused(r"missing: no such file or directory", tmp_path / "missing")


def test_a_corrupt_bag_is_refused_in_one_line(tmp_path):
    """A truncated or garbled storage file, an unknown storage plugin: one-line refusals."""
    stamps, q, v, e = _source(2000)
    topics = {"/joint_states": (JointState.__msgtype__, _states(stamps, q, v, e))}
    db = next(_write(tmp_path / "db", "sqlite3", topics).glob("*.db3"))
    data = db.read_bytes()
    db.write_bytes(data[: len(data) // 2])
    for path in (db, db.parent):
        assert is_bag(path)
        _refused(r"not a readable ROS 2 bag: .*malformed", path)
    garbled = bytearray(data)
    garbled[len(data) - 3000 : len(data) - 1000] = b"\xa5" * 2000
    db.write_bytes(bytes(garbled))
    _refused(r"db\.db3: not a readable ROS 2 bag", db)

    mcap = next(_write(tmp_path / "mc", "mcap", topics).glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[:-100])
    _refused(r"mc\.mcap: not a readable ROS 2 bag", mcap)

    meta = _write(tmp_path / "odd", "sqlite3", topics) / "metadata.yaml"
    meta.write_text(meta.read_text().replace("storage_identifier: sqlite3", "storage_identifier: leveldb"))
    _refused(r"odd: not a readable ROS 2 bag: .*'leveldb' not supported", meta.parent)


def test_without_rosbags_the_extra_is_named(tmp_path, monkeypatch):
    stamps, q, v, e = _source(10)
    bag = _write(tmp_path / "b", "sqlite3", {"/joint_states": (JointState.__msgtype__, _states(stamps, q, v, e))})
    for module in [m for m in sys.modules if m == "rosbags" or m.startswith("rosbags.")]:
        monkeypatch.setitem(sys.modules, module, None)
    assert _refused(r"b: reading a ROS 2 bag needs the formats extra", bag).endswith(NEEDS_EXTRA)


def test_a_bag_beyond_the_memory_budget_is_refused_unread(tmp_path, monkeypatch):
    stamps, q, v, e = _source()
    bag = _write(tmp_path / "big", "mcap", {"/joint_states": (JointState.__msgtype__, _states(stamps, q, v, e))})
    monkeypatch.setenv("MANUS_MEMORY_GB", str(8.0 * 2000 * 4 / 1e9))  # room for 2000 rows of 4 numbers, not 8
    _refused("2000 messages on /joint_states", bag)
