"""ROS 2 bags as recordings: a rosbag2 directory (sqlite3 `.db3` or MCAP storage, with its
`metadata.yaml`), or one `.db3`/`.mcap` file, read with `rosbags` (the `formats` extra; no ROS
installation).

A `sensor_msgs/msg/JointState` topic gives the columns: `t` [s] from the header stamps, relative
to the first (its absolute stamp in the metadata's `start_stamp_ns`); `q1..qn` its positions;
`tau1..taun` its efforts, or a command topic's torques held to each state stamp; `v1..vn` its
velocities, where every sample has them (a driver's estimate, not the true `qd`). Rows come in
stamp order, neither resampled nor repaired: `manus.plants.recording` repairs the time base later.
A bag that cannot be read, or that does not hold what a recording needs, is refused in one line
(`manus.plants.reading.fail`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from manus.plants.errors import RecordingError
from manus.plants.reading import fail, memory_budget, over_budget

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT_ARRAY = "std_msgs/msg/Float64MultiArray"
STORAGE_SUFFIXES = (".db3", ".mcap")  # the storage files rosbags reads alone (its own spelling)
NEEDS_EXTRA = "reading a ROS 2 bag needs the formats extra: pip install 'manus[formats]'"


def is_bag(path: Path) -> bool:
    """A rosbag2 directory (one holding `metadata.yaml`) or a `.db3`/`.mcap` file; by name only,
    so that a corrupt bag still reaches `read_bag` and its refusal."""
    path = Path(path)
    if path.is_dir():
        return (path / "metadata.yaml").is_file()
    return path.suffix in STORAGE_SUFFIXES and path.is_file()


class _Rows:
    """Rows of a fixed width appended one at a time (an array doubled as it fills: about the size
    of the numbers, not a Python object per message)."""

    def __init__(self, width: int, dtype: Any = float):
        self.a = np.empty((256, width), dtype)
        self.n = 0

    def add(self, row) -> None:
        if self.n == len(self.a):
            self.a = np.concatenate([self.a, np.empty_like(self.a)])
        self.a[self.n] = row
        self.n += 1

    def array(self) -> np.ndarray:
        return self.a[: self.n]


def _listing(topics: dict[str, str]) -> str:
    return ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "no topics"


def _stamp(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def _storage(path: Path) -> list[str]:
    """Refuse a path that is no bag (naming what would be); notes on what will be read."""
    if not path.exists():
        fail(path, None, "no such file or directory")
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            inside = sorted(p.name for p in path.iterdir() if p.suffix in STORAGE_SUFFIXES)
            hint = f" (give its storage file: {', '.join(inside)})" if inside else ""
            fail(path, None, f"a directory without metadata.yaml: not a ROS 2 bag{hint}")
        return []
    if path.suffix not in STORAGE_SUFFIXES:
        fail(path, None, "not a ROS 2 bag: a rosbag2 directory (with metadata.yaml), a .db3 or a .mcap file")
    siblings = [p for p in path.parent.iterdir() if p.suffix == path.suffix and p != path]
    if siblings and (path.parent / "metadata.yaml").is_file():
        return [
            f"one of the {len(siblings) + 1} storage files of the bag in {path.parent}: only it is read "
            "(give the directory to read them all)"
        ]
    return []


def read_bag(
    path: Path, topic: str | None = None, joints: list[str] | None = None, command_topic: str | None = None
) -> tuple[dict[str, np.ndarray], dict[str, str], list[str]]:
    """The recording a ROS 2 bag holds: (columns, metadata, notes).

    `topic`: the `sensor_msgs/msg/JointState` topic (default: the bag's only one). `joints`: the
    joints, by name, in column order (default: the first message's names, in its order); a
    message lacking one, or whose positions (or efforts, the torque) are shorter than its names,
    is skipped. Time: the header stamps (a message with an unset, zero, stamp among set ones
    dropped); where all are unset, the bag's receive times.
    `command_topic`: the commanded torque instead of the efforts, a JointState's efforts (by
    name) or a `std_msgs/msg/Float64MultiArray`'s data (in the joints' order, at its receive
    time), the latest at or before each state stamp (state samples before the first command
    dropped). Metadata: `source`, `joint_names`, `torque_from`, `time_from`, `start_stamp_ns`."""
    path = Path(path)
    notes = _storage(path)
    try:
        from rosbags.rosbag2 import Reader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        fail(path, None, NEEDS_EXTRA)
    try:
        store = get_typestore(Stores.LATEST)
        with Reader(path) as reader:
            return _read(path, reader, store, topic, joints, command_topic, notes)
    except (RecordingError, MemoryError):
        raise
    except Exception as e:  # a corrupt bag: rosbags', sqlite's or the decoder's error, in one line
        what = " ".join(str(e).split()) or type(e).__name__
        fail(path, None, f"not a readable ROS 2 bag: {what}")


def _read(path: Path, reader: Any, store: Any, topic, joints, command_topic, notes: list[str]):
    types: dict[str, str] = {}
    for c in reader.connections:
        types[c.topic] = c.msgtype if types.get(c.topic, c.msgtype) == c.msgtype else "several types"
    topic = _state_topic(path, types, topic)
    if command_topic is not None:
        _check_command_topic(path, types, topic, command_topic)
    if joints is not None:
        twice = sorted({j for j in joints if joints.count(j) > 1})
        if twice:
            fail(path, None, f"joint {', '.join(twice)} named more than once")
        if not joints:
            fail(path, None, "no joints chosen")

    s = _States(path, topic, joints)
    chosen = [c for c in reader.connections if c.topic == topic]
    count = sum(int(c.msgcount) for c in chosen)
    for k, (conn, received, raw) in enumerate(reader.messages(connections=chosen)):
        msg = store.deserialize_cdr(raw, conn.msgtype)
        if k == 0:  # the rows' size known from the first message: what would exceed the budget is refused unread
            need = 8.0 * count * (3 * max(len(joints or msg.name), 1) + 2)
            if need > memory_budget():
                over_budget(path, need, f"its {count} messages on {topic}")
        s.add(msg, received)
    names, values, stamps, flags = s.result(notes)
    n = len(names)
    if command_topic is None:
        has_effort = flags[:, 0]
        if not has_effort.any():
            fail(
                path,
                None,
                f"the torque is missing: no efforts on {topic} (a topic of commanded torques: --command-topic)",
            )
        if not has_effort.all():
            notes.append(
                f"{int((~has_effort).sum())} of {s.total} messages on {topic} skipped: fewer efforts than names "
                "(left empty by the publisher)"
            )
            values, stamps, flags = values[has_effort], stamps[has_effort], flags[has_effort]
    t_ns, keep, time_from = _times(stamps, True, topic, notes)
    values, t_ns, flags = values[keep], t_ns[keep], flags[keep]

    if command_topic is None:
        tau = values[:, n : 2 * n]
        torque_from = f"{topic} effort"
    else:
        kind = types[command_topic]
        c_ns, c_tau, c_time_from = _commands(path, reader, store, command_topic, kind, names, notes)
        if c_time_from != time_from:
            notes.append(
                f"the {c_time_from} of {command_topic} are matched to the {time_from} of {topic}, as if on one clock"
            )
        latest = np.searchsorted(c_ns, t_ns, side="right") - 1  # the latest command at or before each sample
        early = latest < 0
        if early.all():
            fail(path, None, f"no sample on {topic} at or after the first command on {command_topic}")
        if early.any():
            notes.append(f"{int(early.sum())} samples on {topic} before the first command on {command_topic} dropped")
            values, t_ns, flags, latest = values[~early], t_ns[~early], flags[~early], latest[~early]
        tau = c_tau[latest]
        field = "data" if kind == FLOAT_ARRAY else "effort"
        torque_from = f"{command_topic} ({kind} {field}), the latest at each state stamp"

    order = np.argsort(t_ns, kind="stable")
    t_ns, values, tau, flags = t_ns[order], values[order], tau[order], flags[order]
    cols: dict[str, np.ndarray] = {"t": (t_ns - t_ns[0]) / 1e9}  # (the differences exact in int64 ns)
    cols.update({f"q{i + 1}": np.ascontiguousarray(values[:, i]) for i in range(n)})
    cols.update({f"tau{i + 1}": np.ascontiguousarray(tau[:, i]) for i in range(n)})
    if flags[:, 1].all():
        cols.update({f"v{i + 1}": np.ascontiguousarray(values[:, 2 * n + i]) for i in range(n)})
    elif flags[:, 1].any():
        notes.append(f"velocities left out: {int((~flags[:, 1]).sum())} of {len(flags)} samples on {topic} lack them")
    meta = {
        "source": f"ROS 2 bag, {topic} ({JOINT_STATE})",
        "joint_names": ",".join(names),
        "torque_from": torque_from,
        "time_from": time_from,
        "start_stamp_ns": str(int(t_ns[0])),
    }
    return cols, meta, notes


def _state_topic(path: Path, types: dict[str, str], topic: str | None) -> str:
    """The JointState topic asked for, else the bag's only one."""
    if topic is None:
        states = sorted(t for t, ty in types.items() if ty == JOINT_STATE)
        if not states:
            fail(path, None, f"no {JOINT_STATE} topic: the bag has {_listing(types)}")
        if len(states) > 1:
            fail(path, None, f"several {JOINT_STATE} topics ({', '.join(states)}): choose one with --topic")
        return states[0]
    if topic not in types:
        fail(path, None, f"no topic {topic}: the bag has {_listing(types)}")
    if types[topic] != JOINT_STATE:
        fail(path, None, f"topic {topic} holds {types[topic]}, not {JOINT_STATE}")
    return topic


def _check_command_topic(path: Path, types: dict[str, str], topic: str, command_topic: str) -> None:
    if command_topic not in types:
        fail(path, None, f"no command topic {command_topic}: the bag has {_listing(types)}")
    if command_topic == topic:
        fail(path, None, f"the command topic is the state topic {topic}: leave it out to read its efforts")
    if types[command_topic] not in (JOINT_STATE, FLOAT_ARRAY):
        fail(
            path,
            None,
            f"command topic {command_topic} holds {types[command_topic]}: a command topic is a "
            f"{JOINT_STATE} (its efforts) or a {FLOAT_ARRAY} (its data)",
        )


def _index(cache: dict, key: tuple[str, ...], names: list[str]) -> np.ndarray | None:
    """Where each of `names` is in a message's name list `key` (None: one is not there)."""
    if key not in cache:
        where = {k: i for i, k in enumerate(key)}
        cache[key] = np.array([where[j] for j in names], int) if all(j in where for j in names) else None
    return cache[key]


class _States:
    """A JointState topic's messages, one at a time: per message the chosen joints' positions,
    efforts and velocities (NaN where the message has too few), (header stamp, receive time),
    and whether it had efforts and velocities."""

    def __init__(self, path: Path, topic: str, joints: list[str] | None):
        self.path, self.topic = path, topic
        self.names = list(joints) if joints else None
        self.seen: dict[str, None] = {}  # the joint names on the topic, in order of appearance
        self.cache: dict = {}
        self.rows: tuple[_Rows, _Rows, _Rows] | None = None
        self.lacking = self.short = self.total = 0

    def add(self, msg: Any, received: int) -> None:
        self.total += 1
        key = tuple(msg.name)
        self.seen.update(dict.fromkeys(key))
        if self.names is None and key:
            self.names = list(key)
        if self.names is None:
            self.lacking += 1
            return
        n = len(self.names)
        if self.rows is None:
            self.rows = (_Rows(3 * n), _Rows(2, np.int64), _Rows(2, bool))
        idx = _index(self.cache, key, self.names)
        if idx is None:
            self.lacking += 1
            return
        if len(msg.position) < len(key):
            self.short += 1
            return
        has_effort, has_velocity = len(msg.effort) >= len(key), len(msg.velocity) >= len(key)
        row = np.full(3 * n, np.nan)
        row[:n] = msg.position[idx]
        if has_effort:
            row[n : 2 * n] = msg.effort[idx]
        if has_velocity:
            row[2 * n :] = msg.velocity[idx]
        self.rows[0].add(row)
        self.rows[1].add((_stamp(msg), received))
        self.rows[2].add((has_effort, has_velocity))

    def result(self, notes: list[str]) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
        """(names, values, stamps, flags); a refusal where the topic holds no joint asked for."""
        path, topic = self.path, self.topic
        if not self.total:
            fail(path, None, f"no messages on {topic}")
        if self.names is None or self.rows is None:
            fail(path, None, f"no message on {topic} names a joint")
        missing = [j for j in self.names if j not in self.seen]
        if missing:
            fail(path, None, f"no joint {', '.join(missing)} on {topic}: its joints are {', '.join(self.seen)}")
        if self.lacking:
            notes.append(f"{self.lacking} of {self.total} messages on {topic} skipped: their names lack a joint read")
        if self.short:
            notes.append(f"{self.short} of {self.total} messages on {topic} skipped: fewer positions than names")
        if not self.rows[0].n:
            fail(path, None, f"no message on {topic} holds the positions of {', '.join(self.names)}")
        return self.names, self.rows[0].array(), self.rows[1].array(), self.rows[2].array()


def _commands(
    path: Path, reader: Any, store: Any, topic: str, kind: str, names: list[str], notes: list[str]
) -> tuple[np.ndarray, np.ndarray, str]:
    """A command topic's (times [ns], torques, what the times are), in time order: a JointState's
    efforts by name, a Float64MultiArray's data as given (one value per joint, no header)."""
    n = len(names)
    torques, stamps = _Rows(n), _Rows(2, np.int64)
    cache: dict = {}
    lacking = short = total = 0
    for conn, received, raw in reader.messages(connections=[c for c in reader.connections if c.topic == topic]):
        msg: Any = store.deserialize_cdr(raw, conn.msgtype)
        total += 1
        if kind == FLOAT_ARRAY:
            if len(msg.data) != n:
                short += 1
                continue
            torques.add(msg.data)
            stamps.add((received, received))
            continue
        key = tuple(msg.name)
        idx = _index(cache, key, names)
        if idx is None:
            lacking += 1
            continue
        if len(msg.effort) < len(key):
            short += 1
            continue
        torques.add(msg.effort[idx])
        stamps.add((_stamp(msg), received))
    if not total:
        fail(path, None, f"no messages on the command topic {topic}")
    too_few = f"data not of {n} values ({', '.join(names)})" if kind == FLOAT_ARRAY else "fewer efforts than names"
    if not torques.n:
        why = "their names lack a joint read" if lacking else too_few
        fail(path, None, f"no usable message on the command topic {topic}: {why}")
    for k, why in ((lacking, "their names lack a joint read"), (short, too_few)):
        if k:
            notes.append(f"{k} of {total} messages on {topic} skipped: {why}")
    t_ns, keep, time_from = _times(stamps.array(), kind != FLOAT_ARRAY, topic, notes)
    t_ns, values = t_ns[keep], torques.array()[keep]
    order = np.argsort(t_ns, kind="stable")  # (equal times: the later message holds)
    return t_ns[order], values[order], time_from


def _times(stamps: np.ndarray, header: bool, topic: str, notes: list[str]) -> tuple[np.ndarray, np.ndarray, str]:
    """(times [ns], which to keep, what they are) from (header stamp, receive time) rows: the
    header stamps; where all are unset (zero) or there is no header, the receive times (a note
    for unset ones); messages with an unset stamp among set ones are dropped, with a note."""
    header_ns, received = stamps[:, 0], stamps[:, 1]
    unset = header_ns == 0
    if header and unset.all():
        notes.append(f"header stamps unset on {topic}: the bag's receive times used")
    if not header or unset.all():
        return received.copy(), np.ones(len(received), bool), "receive times"
    if unset.any():
        notes.append(f"{int(unset.sum())} messages on {topic} with unset header stamps (zero) dropped")
    return header_ns.copy(), ~unset, "header stamps"
