"""The rig emulator: the JAX simulator, in real time, behind the device protocol.

It plays the real-time target of the rig. A HELLO opens a session (the arm is reset to rest at
its start position and an INFO answers); from then on, every period T:

1. the command that answered the previous sample is applied over the period just ended (the
   simulation's order: read, compute, write; the `delay` effect adds the amplifier's lag). If it
   has not arrived, the last command is held and the sample is flagged LATE; if no valid
   command came for `watchdog` seconds, the torque drops to zero and stays there for the
   session (WATCHDOG). A non-finite command means zero torque too (FAULT). Volts are clipped
   to the D/A's range, torques to what the chain can deliver (SATURATED);
2. the physics is stepped (`Simulator.step`, jitted once, with the actuator's D/A and the
   encoder), the encoder counts are sent as a SENSOR packet stamped with the device clock.

A CMD_STOP ends the session at zero torque; after a watchdog trip the emulator keeps streaming
(at zero torque) for `linger` seconds, then waits for the next HELLO. Only the session's host
may command it; packets from anyone else, and malformed or out-of-order ones, are counted and
dropped. For fault injection, `drop` loses that fraction of the packets each way and `garbage`
sends that fraction of junk datagrams before sensor packets. `log` writes what the device did
(measured and true positions, applied torques, flags, whether the fault was on) as a streamed
recording.

`fault` plays a rig gone wrong, from `fault_at` seconds after each HELLO by the device's own clock
(its samples: from sample seq ⌈fault_at / T⌉ on, however late a loaded machine ran them) to the
end of that session (CMD_STOP, a watchdog trip's linger, or a new HELLO), whatever the host
commands:

- `runaway`: joint 1's motor driver delivers the D/A's full scale (volt_limit × torque_per_volt,
  positive; through the D/A its largest code), the other joints what is commanded;
- `stall`: an obstacle blocks the arm: the physics is held where it was (positions frozen,
  velocities zero), so every sample reports the counts of the onset;
- `jump`: a broken encoder line: joint 1 reports 2**31 - 1 counts (INT32_MAX), the physics goes on;
- `bad-info`: the INFO packet says volt_limit = +inf (everything else true; the D/A keeps its
  true range). It is the session's INFO: this fault is on from the HELLO, whatever `fault_at`;
- `late`: each sample is sent `LATE_NS` after it was taken (stamped with the time it was taken;
  the loop sends it while it waits for later periods), so the host's commands miss their deadlines.
"""

from __future__ import annotations

import contextlib
import gc
import math
import select
import socket
import time
from collections import Counter, deque
from pathlib import Path

import numpy as np

from manus.plants import protocol as P
from manus.plants.device import WARM_EVERY_NS, WARM_GAP_NS
from manus.plants.errors import ManusError
from manus.plants.realtime import PRIORITY, Realtime
from manus.plants.recording import RecordingWriter
from manus.plants.simulator import Simulator

FAULTS = ("runaway", "stall", "jump", "bad-info", "late")  # see the module docstring
INT32_MAX = 2**31 - 1  # the counts a broken encoder line reports (`jump`)
LATE_NS = 3_000_000  # how long after it was taken a sample is sent (`late`)


class Emulator:
    """`Emulator(sim, port).serve()`; see the module docstring."""

    def __init__(
        self,
        sim: Simulator,
        port: int,
        host: str = "127.0.0.1",
        watchdog: float = 0.005,
        linger: float = 1.0,
        drop: float = 0.0,
        garbage: float = 0.0,
        log=None,
        seed: int = 0,
        spin: float = 0.002,
        fault: str | None = None,
        fault_at: float = 1.0,
        realtime: bool = False,
    ):
        import jax
        import jax.numpy as jnp

        encoder = sim.encoder
        if encoder is None or sim.actuator is None:
            raise ManusError("the emulator needs a simulator with an encoder and an actuator (a rig has both)")
        if not (0 <= drop < 1 and 0 <= garbage < 1):
            raise ManusError(f"drop and garbage are fractions in [0, 1), got {drop} and {garbage}")
        if fault is not None and fault not in FAULTS:
            raise ManusError(f"unknown fault {fault!r}: the emulator plays {', '.join(FAULTS)}")
        if not (math.isfinite(fault_at) and fault_at >= 0):
            raise ManusError(f"fault_at is seconds after the session starts (finite, >= 0), got {fault_at}")
        self.fault, self.fault_at_ns = fault, int(round(fault_at * 1e9))
        self.sim, self.watchdog, self.linger = sim, float(watchdog), float(linger)
        self.drop, self.garbage = float(drop), float(garbage)
        self.rng = np.random.default_rng(seed)
        self._next_warm = 0
        self._rows, self._last = [], None
        self.realtime = realtime  # SCHED_FIFO while serving, waits by blocking (no spin, no warm ticks)
        self.scheduling = "ordinary (spins before each period)"
        self.spin_ns = 0 if realtime else int(spin * 1e9)
        self.n = sim.model.n_joints
        self.period_ns = int(round(1e9 / sim.rate_hz))
        act = sim.actuator
        self.info = P.Info(self.n, sim.rate_hz, 2 * math.pi / float(encoder.step), act.torque_per_volt, act.volts)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind((host, port))
        except OSError as e:
            raise ManusError(f"emulator: cannot listen on udp://{host}:{port} ({e.strerror})") from None
        self.sock.setblocking(False)
        self.port = self.sock.getsockname()[1]

        def tick(state, tau):
            state, _ = sim.step(state, tau)
            q_true, qd_true = sim.truth(state)
            return state, encoder.counts(state.q).astype(np.int64), q_true, qd_true, act(tau)

        def held(state, tau):  # `stall`: the physics stays where it is, at rest
            state = state._replace(
                qd=jnp.zeros_like(state.qd),
                link_qd=None if state.link_qd is None else jnp.zeros_like(state.link_qd),
            )
            q_true, qd_true = sim.truth(state)
            return state, encoder.counts(state.q).astype(np.int64), q_true, qd_true, act(tau)

        self._tick = jax.jit(tick)
        self._held = jax.jit(held)
        self._reset = jax.jit(lambda: sim.reset()[0])
        self.refused: Counter = Counter()
        self.stats: Counter = Counter()
        self.peer = None
        self.session = 0
        self.active = False
        self.onset_seq = 0
        self._pending: deque[tuple[int, bytes]] = deque()
        self._writer = None
        if log is not None:
            cols = (
                ["t"]
                + [f"q{i + 1}" for i in range(self.n)]
                + [f"tau{i + 1}" for i in range(self.n)]
                + [f"qd{i + 1}" for i in range(self.n)]
                + ["flags", "session", "seq", "fault"]
            )
            self._writer = RecordingWriter(
                log,
                cols,
                {
                    "sample_rate_hz": f"{sim.rate_hz:g}",
                    "counts_per_rev": f"{self.info.counts_per_rev:g}",
                    "structure": sim.model.structure.name,
                    **_robot_of(sim.model.structure),
                    "truth": sim.model.spec,
                    "source": "manus emulate (device side)",
                    "streamed": "true",
                    **({"fault": fault, "fault_at": f"{fault_at:g}"} if fault else {}),
                },
            )
        self._warm_up()

    def _warm_up(self) -> None:
        state = self._reset()
        for _ in range(3):
            state, *_ = self._tick(state, np.zeros(self.n))
            if self.fault == "stall":
                self._held(state, np.zeros(self.n))
        self.state = state

    # -- packets --------------------------------------------------------------------------
    def _send(self, data: bytes) -> None:
        assert self.peer is not None, "no session to send to"
        try:
            self.sock.sendto(data, self.peer)
        except OSError:
            self.stats["send_errors"] += 1

    def _start(self, addr, now: int) -> None:
        self.peer, self.active = addr, True
        self.session += 1
        self.state = self._reset()
        self.seq, self.flags, self.cmd_seq = 0, 0, None
        self.tau = np.zeros(self.n)
        self.ack = None  # the sample the held command answers
        self.last_cmd_ns = now
        self.trip_ns = None
        self.saturated = False
        self._last = None
        self.t0 = getattr(self, "t0", now)
        self.onset_seq = 0 if self.fault == "bad-info" else math.ceil(self.fault_at_ns * self.sim.rate_hz / 1e9 - 1e-9)
        self._pending.clear()  # `late`: (when to send, packet), oldest first
        info = self.info._replace(volt_limit=math.inf) if self.fault == "bad-info" else self.info
        self._send(P.encode_info(0, now, info))
        self.next_ns = now + self.period_ns

    def _fault_on(self, seq: int) -> bool:
        """Whether sample `seq` of this session is faulty."""
        return self.fault is not None and seq >= self.onset_seq

    def _handle(self, data: bytes, addr, now: int) -> None:
        try:
            h = P.header(data)
        except P.ProtocolError as e:
            self.refused["address" if self.active and addr != self.peer else e.reason] += 1
            return
        if h.kind == P.HELLO:
            if self.active and addr != self.peer and self.trip_ns is None:
                self.refused["busy"] += 1  # another host while a session runs
            else:
                self._start(addr, now)
            return
        if addr != self.peer:
            self.refused["address"] += 1
            return
        if not self.active:
            self.refused["no_session"] += 1  # e.g. the repeats of a STOP
            return
        if h.kind != P.COMMAND or h.n_joints != self.n:
            self.refused["kind" if h.kind != P.COMMAND else "joints"] += 1
            return
        if self.drop and self.rng.random() < self.drop:
            self.stats["dropped_in"] += 1
            return
        cmd = P.decode(data)
        assert isinstance(cmd, P.Command)  # its header said COMMAND
        if not P.newer(cmd.seq, self.cmd_seq):
            self.refused["order"] += 1
            return
        self.cmd_seq = cmd.seq
        if cmd.flags & P.CMD_STOP:
            self.tau[:] = 0.0
            self.flags |= P.STATUS_STOPPED
            self._log_session_end(now)
            self.active = False
            return
        if self.flags & (P.STATUS_WATCHDOG | P.STATUS_FAULT):
            return  # latched at zero torque for this session
        values = cmd.values.astype(float)
        if not np.all(np.isfinite(values)):
            self.flags |= P.STATUS_FAULT
            self.tau[:] = 0.0
            return
        volts = values if cmd.flags & P.CMD_VOLTS else values / self.info.torque_per_volt
        clipped = np.clip(volts, -self.info.volt_limit, self.info.volt_limit)
        self.saturated = bool(np.any(clipped != volts))
        self.tau = clipped * self.info.torque_per_volt
        self.ack = cmd.ack
        self.last_cmd_ns = now

    def _log_session_end(self, now):
        """The log's last row of a session: the device at zero torque from `now`."""
        if self._writer is not None and self._last is not None:
            q, qd = self._last
            fault = float(self._fault_on(self.seq))
            self._rows.append(
                np.concatenate(
                    [[(now - self.t0) / 1e9], q, np.zeros(self.n), qd, [self.flags, self.session, self.seq, fault]]
                )
            )

    def _drain(self) -> None:
        while True:
            try:
                data, addr = self.sock.recvfrom(2048)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                self.stats["socket_errors"] += 1
                return
            self._handle(data, addr, time.perf_counter_ns())

    def _send_due(self, now: int) -> None:
        """`late`: send the held-back samples whose time has come."""
        while self._pending and self._pending[0][0] <= now:
            self._send(self._pending.popleft()[1])

    def _wait_until(self, t_ns: int | None) -> None:
        """Take packets (and send the held-back samples) until `t_ns` (perf_counter_ns); None:
        block until one arrives (idle)."""
        clock = time.perf_counter_ns
        while True:
            self._drain()
            if t_ns is None:
                if self.active:
                    return
                select.select([self.sock], [], [], 0.2)
                continue
            now = clock()
            if self.active:
                self._send_due(now)
            if now >= t_ns:
                return
            wake = min(t_ns, self._pending[0][0]) if self.active and self._pending else t_ns
            if self.active and not self.realtime and wake - now > WARM_GAP_NS and now >= self._next_warm:
                self._tick(self.state, self.tau)  # thrown away: keeps the step in the caches (3x faster)
                self._next_warm = clock() + WARM_EVERY_NS
                continue
            if wake - now > self.spin_ns:
                select.select([self.sock], [], [], (wake - now - self.spin_ns) / 1e9)

    # -- the real-time tick ---------------------------------------------------------------
    def _period(self, now: int) -> None:
        flags = self.flags & ~(P.STATUS_LATE | P.STATUS_SATURATED)
        if self.seq > 0 and self.ack != self.seq and not flags & (P.STATUS_WATCHDOG | P.STATUS_FAULT):
            flags |= P.STATUS_LATE
            self.stats["late"] += 1
        if now - self.last_cmd_ns > self.watchdog * 1e9 and not flags & P.STATUS_WATCHDOG:
            flags |= P.STATUS_WATCHDOG
            self.trip_ns = now
            self.stats["watchdog_trips"] += 1
        if flags & (P.STATUS_WATCHDOG | P.STATUS_FAULT):
            self.tau[:] = 0.0
        elif self.saturated:
            flags |= P.STATUS_SATURATED
        self.flags = flags
        fault = self.fault if self._fault_on(self.seq + 1) else None  # (the sample made now)
        tau = self.tau
        if fault == "runaway":
            tau = tau.copy()
            tau[0] = self.info.volt_limit * self.info.torque_per_volt
        step = self._held if fault == "stall" else self._tick
        self.state, counts, _q_true, qd_true, applied = step(self.state, tau)
        counts = np.array(counts)
        if fault == "jump":
            counts[0] = INT32_MAX
        self.seq += 1
        if self.garbage and self.rng.random() < self.garbage:
            self._send(self._junk())
            self.stats["garbage_sent"] += 1
        if self.drop and self.rng.random() < self.drop:
            self.stats["dropped_out"] += 1
        elif fault == "late":
            self._pending.append((now + LATE_NS, P.encode_sensor(self.seq, now, counts, flags)))
        else:
            self._send(P.encode_sensor(self.seq, now, counts, flags))
        self.stats["ticks"] += 1
        if self._writer is not None:
            q = counts * (2 * math.pi / self.info.counts_per_rev)
            self._last = (q, np.asarray(qd_true))
            row = np.concatenate(
                [
                    [(now - self.t0) / 1e9],
                    q,
                    np.asarray(applied),
                    self._last[1],
                    [flags, self.session, self.seq, float(fault is not None)],
                ]
            )
            self._rows.append(row)
            if len(self._rows) >= 20:
                self._writer.append(np.array(self._rows))
                self._rows.clear()

    def _junk(self) -> bytes:
        kind = self.rng.integers(4)
        if kind == 0:  # random bytes
            return self.rng.bytes(int(self.rng.integers(1, 64)))
        good = bytearray(P.encode_sensor(self.seq, 0, np.zeros(self.n), 0))
        if kind == 1:  # a flipped bit: the CRC catches it
            good[int(self.rng.integers(len(good)))] ^= 1 << int(self.rng.integers(8))
        elif kind == 2:  # another version
            good[2] = P.VERSION + 1
        else:  # cut short
            good = good[:-3]
        return bytes(good)

    def serve(self, seconds: float | None = None) -> dict:
        """Run until `seconds` have passed (None: until interrupted) -> counters."""
        clock = time.perf_counter_ns
        end = None if seconds is None else clock() + int(seconds * 1e9)
        gc.collect()
        gc.disable()
        try:
            with Realtime(PRIORITY - 1) if self.realtime else contextlib.nullcontext() as rt:
                if rt is not None:
                    self.scheduling = rt.why
                self._serve(end)
        finally:
            gc.enable()
            self.close()
        return {"refused": dict(self.refused), **dict(self.stats)}

    def _serve(self, end: int | None) -> None:
        """The periods until `end` (perf_counter_ns; None: until interrupted)."""
        clock = time.perf_counter_ns
        while end is None or clock() < end:
            if not self.active:
                if self._rows and self._writer is not None:
                    self._writer.append(np.array(self._rows))
                    self._rows.clear()
                    self._writer.flush()
                self._wait_until(None) if end is None else self._idle_until(end)
                continue
            self._wait_until(self.next_ns)
            if not self.active:
                continue
            now = clock()
            if now - self.next_ns > self.period_ns:  # this process was held up: resynchronize
                self.stats["overruns"] += 1
                self.next_ns = now
            self._period(now)
            self.next_ns += self.period_ns
            if self.trip_ns is not None and now - self.trip_ns > self.linger * 1e9:
                self.active = False

    def _idle_until(self, end: int) -> None:
        self._drain()
        if not self.active:
            select.select([self.sock], [], [], max(0.0, min(0.2, (end - time.perf_counter_ns()) / 1e9)))

    def close(self) -> None:
        if self._writer is not None:
            if getattr(self, "_rows", None):
                self._writer.append(np.array(self._rows))
                self._rows.clear()
            self._writer.close()
        self.sock.close()


def _robot_of(structure) -> dict:
    """A serial chain's log names its URDF (absolute: the log may go anywhere)."""
    source = structure.urdf_file
    return {"robot": str(Path(source).absolute())} if source else {}
