"""The device interface the hardware loop talks to, and its UDP transport.

    device = open_device("udp://127.0.0.1:5555")
    info = device.connect()                      # HELLO -> INFO: joints, rate, encoder, D/A
    sample = device.receive(deadline_ns)         # the next valid SENSOR packet, or None
    device.send(sample.seq, volts, CMD_VOLTS)    # the command answering it
    device.stop(); device.close()                # zero torque, end of session

The device owns the clock: it samples the encoders at its rate and streams SENSOR packets; the
host answers each with a COMMAND before the next sample (see `manus.plants.protocol`). Another
transport (a serial line, shared memory to a real-time target) replaces `UdpDevice` by
implementing `Device`. Every packet refused (another sender, wrong length, version, magic,
kind, joint count or CRC, out of order) is counted in `refused` by reason, never acted on.
"""

from __future__ import annotations

import abc
import select
import socket
import time
from collections import Counter
from urllib.parse import urlparse

import numpy as np

from manus.plants import protocol as P
from manus.plants.errors import ManusError

SPIN_NS = 1_000_000  # busy-wait from 1 ms before an expected packet (see `UdpDevice.receive`)
WARM_GAP_NS, WARM_EVERY_NS = 150_000, 60_000  # `idle` calls stop this long before the expected packet
WARM_BLOCKED_NS = 450_000  # a thread that blocks makes its `idle` calls from this long before it


class DeviceError(ManusError):
    """A device that cannot be reached or that answers nonsense."""


class Device(abc.ABC):
    """A rig seen from the host: connect, receive samples, send commands, stop."""

    info: P.Info | None = None
    url: str = "device"  # where the device is (its address), for messages

    def __init__(self):
        self.refused: Counter = Counter()
        self.sent = 0
        self.received = 0

    @abc.abstractmethod
    def connect(self, timeout: float = 2.0, spin: bool = True) -> P.Info:
        """Open a session -> what the device is. Raises DeviceError when it does not answer.
        `spin=False` (a real-time thread): wait for the answer by blocking."""

    @abc.abstractmethod
    def receive(self, deadline_ns: int, expect_ns: int | None = None, idle=None, spin: bool = True) -> P.Sensor | None:
        """The next valid, newer SENSOR sample arriving before `deadline_ns` (time.perf_counter_ns),
        or None. `expect_ns`: when it should arrive (the wait may busy-spin shortly before);
        `idle()` is called every `WARM_EVERY_NS` while the sample is still more than
        `WARM_GAP_NS` away. `spin=False` (a real-time thread, which must not spin): the wait
        blocks between the `idle()` calls, which start `WARM_BLOCKED_NS` before the sample is due."""

    @abc.abstractmethod
    def send(self, ack: int, values, flags: int = 0) -> None:
        """Send the command answering sample `ack`: volts (flags has CMD_VOLTS) or N·m, per joint."""

    def stop(self, repeats: int = 3) -> None:
        """Zero torque and end the session (sent a few times: a datagram can be lost)."""
        if self.info is None:
            return
        for _ in range(repeats):
            try:
                self.send(0, np.zeros(self.info.n_joints), P.CMD_STOP)
            except OSError:
                return

    @abc.abstractmethod
    def close(self) -> None: ...

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class UdpDevice(Device):
    """A device at `host:port` over UDP. Only datagrams from exactly that address are taken."""

    def __init__(self, host: str, port: int, bind: str = ""):
        super().__init__()
        self.url = f"udp://{host}:{port}"
        try:
            self.peer = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4]
        except (socket.gaierror, OSError) as e:
            raise DeviceError(f"{self.url}: cannot resolve the device's address ({e})") from None
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind((bind or ("127.0.0.1" if str(self.peer[0]).startswith("127.") else ""), 0))
        self.sock.setblocking(False)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        self.seq = 0
        self.last_seq: int | None = None
        self.flags = 0  # the device's status flags in its last sample
        self.spin_after_ns = 1_000_000  # keep spinning this long past the expected arrival

    @property
    def address(self) -> tuple[str, int]:
        return self.sock.getsockname()

    def _send(self, data: bytes) -> None:
        self.sock.sendto(data, self.peer)
        self.sent += 1

    def _packet(self):
        """One datagram from the socket -> decoded packet, or None (nothing waiting / refused)."""
        try:
            data, addr = self.sock.recvfrom(2048)
        except BlockingIOError:
            return None
        except OSError:  # e.g. an ICMP "port unreachable" reported on the socket
            self.refused["unreachable"] += 1
            return None
        if addr != self.peer:
            self.refused["address"] += 1
            return None
        try:
            return P.decode(data)
        except P.ProtocolError as e:
            self.refused[e.reason] += 1
            return None

    def connect(self, timeout: float = 2.0, spin: bool = True) -> P.Info:
        while True:  # forget what an earlier session left in the socket
            try:
                self.sock.recvfrom(2048)
            except (BlockingIOError, OSError):
                break
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            self.seq += 1
            self._send(P.encode_hello(self.seq, time.perf_counter_ns(), 1))
            wait_until = min(end, time.monotonic() + 0.1)
            while (now := time.monotonic()) < wait_until:  # busy unless asked not to: the first samples follow at once
                if not spin:
                    select.select([self.sock], [], [], wait_until - now)
                packet = self._packet()
                if isinstance(packet, P.Info):
                    self.info = packet
                    self.last_seq = None
                    if packet.problem():  # nothing is computed from a description that cannot be true
                        self.stop()
                        raise DeviceError(f"{self.url}: the device's INFO {packet.problem()}: refusing to drive it")
                    return packet
        raise DeviceError(
            f"{self.url}: no answer from the device within {timeout:g} s "
            f"(is `manus emulate --port {self.peer[1]}` or the rig running?)"
        )

    def receive(self, deadline_ns: int, expect_ns: int | None = None, idle=None, spin: bool = True) -> P.Sensor | None:
        sock, clock = self.sock, time.perf_counter_ns
        info = self.info
        assert info is not None, f"{self.url}: receive before connect"
        warm_until = (expect_ns - WARM_GAP_NS) if (idle is not None and expect_ns is not None) else 0
        next_warm = 0
        if not spin and expect_ns is not None:  # (a real-time thread: blocked until WARM_BLOCKED_NS before)
            next_warm = expect_ns - WARM_BLOCKED_NS
        while True:
            packet = self._packet()
            if packet is not None:
                if isinstance(packet, P.Sensor) and packet.counts.size == info.n_joints:
                    if P.newer(packet.seq, self.last_seq):
                        self.last_seq = packet.seq
                        self.flags = packet.flags
                        self.received += 1
                        return packet
                    self.refused["order"] += 1
                else:
                    self.refused["kind" if not isinstance(packet, P.Sensor) else "joints"] += 1
                continue
            now = clock()
            if now >= deadline_ns:
                return None
            if idle is not None and now < warm_until and now >= next_warm:
                idle()  # e.g. keep the compiled tick in the caches
                next_warm = clock() + WARM_EVERY_NS
                continue
            if not spin:
                wake = next_warm if idle is not None and now < next_warm < warm_until else deadline_ns
                select.select([sock], [], [], max(0, min(wake, deadline_ns) - now) / 1e9)
                continue
            # Busy-wait from just before the expected arrival to one period after it: on a VM an
            # idle vCPU can take milliseconds to wake from select (measured), a spinning one does not.
            if expect_ns is None or not expect_ns - SPIN_NS <= now <= expect_ns + self.spin_after_ns:
                wake = expect_ns - SPIN_NS if expect_ns is not None and now < expect_ns - SPIN_NS else deadline_ns
                select.select([sock], [], [], max(0, min(wake, deadline_ns) - now) / 1e9)

    def send(self, ack: int, values, flags: int = 0) -> None:
        self.seq += 1
        self._send(P.encode_command(self.seq, time.perf_counter_ns(), ack, values, flags))

    def close(self) -> None:
        self.sock.close()


def open_device(url: str) -> Device:
    """A device by URL: `udp://HOST:PORT`."""
    u = urlparse(url)
    if u.scheme != "udp":
        raise DeviceError(f"device {url!r}: unknown transport {u.scheme or '(none)'!r} (expected udp://HOST:PORT)")
    try:
        port = u.port
    except ValueError:
        port = None
    if not u.hostname or not port:
        raise DeviceError(f"device {url!r}: expected udp://HOST:PORT, e.g. udp://127.0.0.1:5555")
    return UdpDevice(u.hostname, port)
