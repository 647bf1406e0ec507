"""The rig's wire protocol: small, versioned binary packets, one each way per control period.

Every packet is little-endian and ends in a CRC-32 of everything before it:

    header (20 bytes): magic b"MN" | version u8 | kind u8 | n_joints u8 | reserved u8 |
                       flags u16 | seq u32 | time_ns u64
    payload:           depends on kind (below)
    trailer (4 bytes): crc32 u32 (zlib.crc32 of header + payload)

| kind | direction | payload | meaning |
|---|---|---|---|
| 1 SENSOR | device → host | n × i32 encoder counts | the sample of tick `seq`, taken at device time `time_ns` |
| 2 COMMAND | host → device | ack u32, n × f32 values | the command answering sample `ack`; volts or N·m by `flags` |
| 3 HELLO | host → device | none | open a session: the device resets, answers INFO, then streams SENSOR |
| 4 INFO | device → host | rate_hz f64, counts_per_rev f64, torque_per_volt f64, volt_limit f64 | what the device is |

SENSOR flags (`STATUS_*`): the device's state. COMMAND flags (`CMD_*`): the command's unit and
whether the host is ending the session (`CMD_STOP`: zero torque, stop streaming). `seq` counts up
by one per packet on each side; a receiver refuses a packet that is not newer than the last one
it took (out of order or repeated). A packet whose length, magic, version, kind, joint count or
CRC is wrong is refused with a `ProtocolError` naming the problem; the receiver counts it.
Version 1 is this layout; a change to it bumps `VERSION`.
"""

from __future__ import annotations

import math
import struct
import zlib
from typing import NamedTuple

import numpy as np

MAGIC = b"MN"
VERSION = 1
SENSOR, COMMAND, HELLO, INFO = 1, 2, 3, 4
KINDS = {SENSOR: "sensor", COMMAND: "command", HELLO: "hello", INFO: "info"}

# SENSOR status flags
STATUS_WATCHDOG = 1 << 0  # no valid command for the watchdog time: zero torque, latched for the session
STATUS_LATE = 1 << 1  # the command answering the previous sample had not arrived in time
STATUS_SATURATED = 1 << 2  # the applied command was clipped at the device's limit
STATUS_FAULT = 1 << 3  # the device refused a non-finite command: zero torque, latched
STATUS_STOPPED = 1 << 4  # the host ended the session (CMD_STOP): zero torque
# COMMAND flags
CMD_VOLTS = 1 << 0  # values are D/A volts (else joint torques, N·m)
CMD_STOP = 1 << 1  # end of session: zero torque now

_HEADER = struct.Struct("<2sBBBBHIQ")
_CRC = struct.Struct("<I")
_INFO = struct.Struct("<dddd")
_ACK = struct.Struct("<I")
MAX_JOINTS = 16


class ProtocolError(ValueError):
    """A packet that is refused. `reason` is a short key for counting: length, magic, version,
    kind, joints, crc."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


class Header(NamedTuple):
    kind: int
    n_joints: int
    flags: int
    seq: int
    time_ns: int


class Sensor(NamedTuple):
    seq: int
    time_ns: int  # device clock when the sample was taken
    counts: np.ndarray  # (n,) int32 encoder counts
    flags: int


class Command(NamedTuple):
    seq: int
    time_ns: int  # host clock when sent
    ack: int  # the SENSOR seq this command answers
    values: np.ndarray  # (n,) float32, volts or N·m
    flags: int


class Info(NamedTuple):
    n_joints: int
    rate_hz: float
    counts_per_rev: float
    torque_per_volt: float
    volt_limit: float

    @property
    def torque_limit(self) -> float:
        return self.volt_limit * self.torque_per_volt

    def problem(self) -> str:
        """What makes this description of a rig unbelievable ('' when nothing does): a rate, an
        encoder, a torque per volt and a D/A range are positive finite numbers, and a rig has joints."""
        if self.n_joints < 1:
            return f"says the device has {self.n_joints} joints"
        for name in ("rate_hz", "counts_per_rev", "torque_per_volt", "volt_limit"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                return f"says {name} = {value!r} (a rig's is a positive finite number)"
        return ""


def size(kind: int, n_joints: int) -> int:
    """The exact length in bytes of a packet of `kind` for `n_joints`."""
    payload = {SENSOR: 4 * n_joints, COMMAND: 4 + 4 * n_joints, HELLO: 0, INFO: _INFO.size}[kind]
    return _HEADER.size + payload + _CRC.size


def _pack(kind, n, flags, seq, time_ns, payload: bytes) -> bytes:
    body = _HEADER.pack(MAGIC, VERSION, kind, n, 0, flags & 0xFFFF, seq & 0xFFFFFFFF, time_ns & (2**64 - 1)) + payload
    return body + _CRC.pack(zlib.crc32(body))


def encode_sensor(seq: int, time_ns: int, counts, flags: int = 0) -> bytes:
    counts = np.asarray(counts, "<i4")
    return _pack(SENSOR, counts.size, flags, seq, time_ns, counts.tobytes())


def encode_command(seq: int, time_ns: int, ack: int, values, flags: int = 0) -> bytes:
    values = np.asarray(values, "<f4")
    return _pack(COMMAND, values.size, flags, seq, time_ns, _ACK.pack(ack & 0xFFFFFFFF) + values.tobytes())


def encode_hello(seq: int, time_ns: int, n_joints: int) -> bytes:
    return _pack(HELLO, n_joints, 0, seq, time_ns, b"")


def encode_info(seq: int, time_ns: int, info: Info) -> bytes:
    return _pack(
        INFO,
        info.n_joints,
        0,
        seq,
        time_ns,
        _INFO.pack(info.rate_hz, info.counts_per_rev, info.torque_per_volt, info.volt_limit),
    )


def header(data: bytes) -> Header:
    """Check a packet's framing (length, magic, version, kind, joints, CRC) -> its header."""
    if len(data) < _HEADER.size + _CRC.size:
        raise ProtocolError(
            "length", f"packet of {len(data)} bytes is shorter than a header ({_HEADER.size + _CRC.size})"
        )
    magic, version, kind, n, _, flags, seq, time_ns = _HEADER.unpack_from(data)
    if magic != MAGIC:
        raise ProtocolError("magic", f"not a manus packet (starts {magic!r}, expected {MAGIC!r})")
    if version != VERSION:
        raise ProtocolError("version", f"protocol version {version}, this side speaks {VERSION}")
    if kind not in KINDS:
        raise ProtocolError("kind", f"unknown packet kind {kind}")
    if not 1 <= n <= MAX_JOINTS:
        raise ProtocolError("joints", f"packet for {n} joints (1..{MAX_JOINTS} allowed)")
    if len(data) != size(kind, n):
        raise ProtocolError(
            "length", f"{KINDS[kind]} packet of {len(data)} bytes, expected {size(kind, n)} for {n} joints"
        )
    (crc,) = _CRC.unpack_from(data, len(data) - _CRC.size)
    if crc != zlib.crc32(data[: -_CRC.size]):
        raise ProtocolError("crc", f"{KINDS[kind]} packet fails its CRC (corrupted)")
    return Header(kind, n, flags, seq, time_ns)


def decode(data: bytes) -> Sensor | Command | Info | Header:
    """Any packet -> Sensor, Command, Info, or the Header of a HELLO; raises ProtocolError."""
    h = header(data)
    p = _HEADER.size
    if h.kind == SENSOR:
        return Sensor(h.seq, h.time_ns, np.frombuffer(data, "<i4", h.n_joints, p), h.flags)
    if h.kind == COMMAND:
        (ack,) = _ACK.unpack_from(data, p)
        return Command(h.seq, h.time_ns, ack, np.frombuffer(data, "<f4", h.n_joints, p + 4), h.flags)
    if h.kind == INFO:
        return Info(h.n_joints, *_INFO.unpack_from(data, p))
    return h


def newer(seq: int, last: int | None) -> bool:
    """Whether `seq` comes after `last` (u32 counters, wrap-around safe; None: nothing seen yet)."""
    return last is None or 0 < ((seq - last) & 0xFFFFFFFF) < 2**31
