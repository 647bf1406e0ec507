"""The hardware loop: any controller stepper (its velocity estimator inside) against a device,
in real time, with safety limits, self-measurement and a recording written as it goes.

    stepper = CompiledTick(controller, reference, dt=1e-3, counts_per_rev=131072)
    result = run_loop(open_device("udp://127.0.0.1:5555"), stepper, seconds=10, record="rec.csv")

Each tick: the device's sample k arrives (encoder counts), the compiled tick turns it into
positions, runs the controller against the reference at t = k T, checks every number for NaN or
Inf and the rig's limits (`manus.plants.limits`: velocity, workspace, encoder jump, stall), and
clamps the torque; the loop checks the limits again on what it received and clamps again (torque,
then volts: no stepper output can pass the limits), sends the command, and logs the row. The
device owns the clock (it samples at its rate); the loop answers each sample before the next one
is due.

Safety: a limit tripped stops the run with zero torque (`stopped_by` "limit"); a non-finite value
anywhere (measurement, controller state, command), or the device reporting FAULT, stops it with
"fault"; no valid sample for `watchdog` seconds, or the device reporting that its own watchdog
fired, stops it with "watchdog"; Ctrl-C or SIGTERM stop it with "user"; on every way out the
device is sent zero torque and the end of the session, and the recording is flushed, its last
lines saying why the run stopped, and closed. The recording reaches the file every 10 ms.

Self-measurement, kept per tick in the recording (`compute_us`, `period_us`, `late`) and
summarized in the result: compute = from the sample in hand to the command sent; jitter = the
interval between consecutive samples in hand minus T; a deadline miss = a command that left more
than one period after its sample was taken (the device clock mapped onto the host's by the
smallest transit seen so far).
"""

from __future__ import annotations

import contextlib
import gc
import math
import signal
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from manus.plants import protocol as P
from manus.plants.device import Device
from manus.plants.errors import ManusError
from manus.plants.limits import LOOP, NONFINITE, Limits, Resolved, check, reason
from manus.plants.realtime import Realtime
from manus.plants.recording import RecordingWriter
from manus.plants.stepper import Controller, Plant, Reference

if TYPE_CHECKING:
    from jax.typing import ArrayLike

STOPS = ("end", "watchdog", "fault", "limit", "user")
FIRST_SAMPLE_TIMEOUT = 0.5  # s: after HELLO, the device's first sample
LOG_EVERY = 10  # rows handed to the writer at once (it writes them to the file then): what a SIGKILL can lose


def realtime_jax() -> None:
    """Run each jitted call on the calling thread, with no hand-off to XLA's pool and back
    (a tick's p50 36 -> 26 µs, p99 4x lower, measured). Call it before JAX computes anything:
    the CPU client reads the setting when it is created."""
    import jax

    jax.config.update("jax_cpu_enable_async_dispatch", False)


class Tick(Protocol):
    """What `run_loop` uses of a stepper (`CompiledTick`, or the numpy baseline of `manus bench
    hardware`): its joints, period, encoder step and extra columns, the limits it runs within
    (`Resolved` once started), and start/step/keep_warm as `CompiledTick`'s."""

    n: int
    dt: float
    q_step: float
    extras: list[str]
    limits: Resolved

    def start(self, counts) -> None: ...

    def step(self, k: int, counts) -> tuple[np.ndarray, np.ndarray, int, bool]: ...

    def keep_warm(self) -> None: ...


class CompiledTick:
    """A controller and a reference compiled into one function of (state, counts, k), jitted
    once with the configuration closed over, the rig's `Limits` checked inside it (`check`). The
    state travels as one flat float vector (the controller's, then the limits' own: the last
    positions and command, how long each joint has been held, the trip, the workspace box) and
    the outputs come back in the same vector, so a tick is one call and one transfer.

    `step(k, counts) -> (tau (n,), extras (m,), trip, clamped)`: the command [N·m] (zero once
    tripped), the values named by `extras` (reference positions, the velocity estimate when the
    controller keeps one: `Controller.velocity`), the trip's code (`manus.plants.limits.TRIPS`;
    0: none; latched: every later tick keeps it and commands zero) and whether the command was
    clamped to the torque limit. A non-finite number anywhere, or the controller stopping itself
    (`Controller.stopped`), trips "non-finite"."""

    def __init__(
        self,
        controller: Controller,
        reference: Reference,
        dt: float,
        counts_per_rev: float,
        n_joints: int,
        limits: Limits | None = None,
        device_torque: float = math.inf,
    ):
        import jax
        import jax.numpy as jnp
        from jax.flatten_util import ravel_pytree

        self.n, self.dt = n_joints, float(dt)
        step = 2 * math.pi / float(counts_per_rev)
        self.q_step = step
        self.rules = limits or Limits()
        self.device_torque = float(device_torque)
        probe = self.rules.resolved(n_joints, np.zeros(n_joints), self.device_torque, self.dt)
        self.limits: Resolved = probe  # (the workspace box set at `start`, from where the rig stands)
        limit = probe.torque
        probe_state = controller.init(jnp.asarray(reference(0.0).q, float))
        flat0, unravel = ravel_pytree(probe_state)
        self.size = int(flat0.size)
        n = n_joints
        velocity = controller.velocity(probe_state)
        has_v = velocity is not None and np.shape(velocity) == (n_joints,)
        self.extras = [f"qref{i + 1}" for i in range(n_joints)] + (
            [f"vhat{i + 1}" for i in range(n_joints)] if has_v else []
        )

        def finite(tree):
            leaves = [x for x in jax.tree.leaves(tree) if jnp.issubdtype(jnp.asarray(x).dtype, jnp.inexact)]
            return jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in leaves])) if leaves else jnp.array(True)

        def tick(flat, counts, k):
            s = self.size
            state = unravel(flat[:s])
            q_prev, tau_prev, held = flat[s : s + n], flat[s + n : s + 2 * n], flat[s + 2 * n : s + 3 * n]
            tripped, low, high = flat[s + 3 * n], flat[s + 3 * n + 1 : s + 4 * n + 1], flat[s + 4 * n + 1 :]
            q = counts * step
            ref = reference(k * dt)
            state, tau = controller.step(state, q, ref)
            ok = finite(state) & jnp.all(jnp.isfinite(tau)) & jnp.all(jnp.isfinite(ref.q)) & jnp.all(jnp.isfinite(q))
            ok = ok & ~jnp.any(jnp.asarray(controller.stopped(state)))  # a latched controller stop
            lim = replace(probe, low=low, high=high)
            code, _, held = check(lim, q, q_prev, 1, tau_prev, held, jnp)
            trip = jnp.where(tripped > 0, tripped, jnp.where(ok, code, NONFINITE).astype(flat.dtype))
            clamped = jnp.any(jnp.abs(tau) > limit) & (trip == 0)
            tau = jnp.where(trip == 0, jnp.clip(tau, -limit, limit), 0.0)
            velocity = controller.velocity(state)
            extra = [ref.q] + ([velocity] if has_v and velocity is not None else [])
            own = [q, tau, held, trip[None], low, high]
            return jnp.concatenate([ravel_pytree(state)[0], *own, tau, *extra, clamped[None].astype(flat.dtype)])

        def init(counts):
            return ravel_pytree(controller.init(counts * step))[0]

        self._tick, self._init = jax.jit(tick), jax.jit(init)
        self.flat = None

    def warm_up(self, calls: int = 5) -> None:
        """Compile and run a few ticks on made-up counts (before the device is opened)."""
        counts = np.zeros(self.n, np.int32)
        self.start(counts)
        for k in range(calls):
            self.step(k, counts)
        self.flat = None

    def start(self, counts) -> None:
        """A run from the rig's first sample: the controller's state, and the workspace box
        resolved around where the rig stands (`Limits.resolved`)."""
        counts = np.asarray(counts, np.int32)
        q = counts * self.q_step
        self.limits = self.rules.resolved(self.n, q, self.device_torque, self.dt)
        own = np.concatenate([q, np.zeros(2 * self.n), [0.0], self.limits.low, self.limits.high])
        self.flat = np.concatenate([np.asarray(self._init(counts)), own])
        self._last = (0, counts)

    def keep_warm(self) -> None:
        """Run the last tick again and throw the result away. Called while waiting for a
        sample: a tick that follows 1 ms of waiting takes about 3x longer than one that follows
        another tick here (caches gone cold; 130 vs 40 µs, measured), and the wait costs nothing."""
        self._tick(self.flat, self._last[1], self._last[0])

    def step(self, k: int, counts):
        out = np.asarray(self._tick(self.flat, counts, k))
        self._last = (k, counts)
        n = self.n
        end = self.size + 5 * n + 1
        self.flat = out[:end]
        trip = int(out[self.size + 3 * n])
        return out[end : end + n], out[end + n : -1], trip, bool(out[-1])


@dataclass
class Result:
    ticks: int = 0
    deadline_misses: int = 0
    compute_us: dict = field(default_factory=dict)
    jitter_us: dict = field(default_factory=dict)
    stopped_by: str = "end"
    reason: str = ""
    lost_samples: int = 0
    device_late: int = 0
    refused: dict = field(default_factory=dict)
    tracking_rms: list = field(default_factory=list)
    max_abs_tau: list = field(default_factory=list)
    recording: str | None = None
    scheduling: str = "ordinary (waits by spinning near each sample)"

    def as_dict(self) -> dict:
        return dict(self.__dict__)


class HardwarePlant(Plant):
    """The rig as a `Plant` (`reset(key) -> (state, q)`, `step(state, command) -> (state, q)`), for
    code written against that interface: an imperative wrapper (brax's pattern), not a pure one, so
    it runs in Python, never inside `jit` or `scan`. The state is the last sample; `step` sends the
    command answering it (clamped to the limits; a non-finite one stops the device and raises) and
    waits for the next. `close()` ends at zero torque. The rig's truth is its encoder: `truth`
    gives the measured position and no velocity (NaN), and its parameters are unknown (`params` {})."""

    device: Device
    watchdog: float
    info: P.Info
    limit: float
    dt: float
    q_step: float

    def __init__(self, device: Device, torque_limit: float | None = None, watchdog: float = 0.02):
        self.device, self.watchdog = device, float(watchdog)
        self.info = device.info or device.connect()
        self.limit = self.info.torque_limit if torque_limit is None else min(torque_limit, self.info.torque_limit)
        self.dt = 1.0 / self.info.rate_hz
        self.q_step = 2 * math.pi / self.info.counts_per_rev

    @property
    def params(self) -> dict:
        return {}

    def _next(self, timeout: float) -> P.Sensor:
        sample = self.device.receive(time.perf_counter_ns() + int(timeout * 1e9))
        if sample is None:
            self.close()
            raise ManusError(f"{self.device.url}: no sample for {timeout * 1e3:g} ms (zero torque sent)")
        return sample

    def reset(self, key=None, q0=None, qd0=None):
        """Open the session and wait for the first sample. The rig starts where it stands: `key`,
        `q0` and `qd0` are not the host's to choose (ignored)."""
        self.device.connect()
        sample = self._next(FIRST_SAMPLE_TIMEOUT)
        return sample, sample.counts * self.q_step

    def step(self, state: P.Sensor, command: ArrayLike | Sequence[float]):
        tau = np.asarray(command, float)
        if not np.all(np.isfinite(tau)):
            self.close()
            raise ManusError(f"non-finite command {tau.tolist()} at sample {state.seq} (zero torque sent)")
        volts = np.clip(
            np.clip(tau, -self.limit, self.limit) / self.info.torque_per_volt,
            -self.info.volt_limit,
            self.info.volt_limit,
        )
        self.device.send(state.seq, volts, P.CMD_VOLTS)
        sample = self._next(self.watchdog)
        return sample, sample.counts * self.q_step

    def truth(self, state: P.Sensor):
        """The measured position of the sample, and NaN velocities: the rig has no other truth."""
        q = state.counts * self.q_step
        return q, np.full(np.shape(q), np.nan)

    def close(self) -> None:
        self.device.stop()


def percentiles(x) -> dict:
    x = np.asarray(x, float)
    if x.size == 0:
        return {"p50": None, "p99": None, "max": None}
    return {
        "p50": round(float(np.percentile(x, 50)), 1),
        "p99": round(float(np.percentile(x, 99)), 1),
        "max": round(float(x.max()), 1),
    }


class _Stop:
    """Ctrl-C and SIGTERM set a flag the loop checks every tick (no exception mid-send)."""

    def __init__(self):
        self.requested = False
        self._old = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                self._old[sig] = signal.signal(sig, self._set)
        return self

    def _set(self, *_):
        self.requested = True

    def __exit__(self, *exc):
        for sig, old in self._old.items():
            signal.signal(sig, old)


def columns(n: int, extras: list[str]) -> list[str]:
    return (
        ["t"]
        + [f"q{i + 1}" for i in range(n)]
        + [f"tau{i + 1}" for i in range(n)]
        + list(extras)
        + ["compute_us", "period_us", "latency_us", "late", "flags", "seq", "clamped", "trip"]
    )


def run_loop(
    device: Device,
    stepper: Tick,
    seconds: float,
    record: str | Path | None = None,
    watchdog: float = 0.02,
    volts: bool = True,
    meta: dict | None = None,
    realtime: bool = False,
) -> Result:
    """Run `stepper` (a `Tick`: a `CompiledTick`, or any with what it declares)
    against `device` for `seconds`; see the module docstring. Connects the device itself. The
    stepper's limits (`manus.plants.limits`) are checked again here on what was received and sent.
    `realtime`: the loop's thread under SCHED_FIFO with its memory locked, waiting for each sample
    by blocking (`manus.plants.realtime`; where refused, as an ordinary process, said in
    `Result.scheduling`); otherwise it spins from just before each sample is due."""
    if not seconds > 0:
        raise ManusError(f"seconds must be positive, got {seconds}")
    if not watchdog > 0:
        raise ManusError(f"the watchdog time must be positive, got {watchdog}")
    info = device.info or device.connect()  # what the device is (the session itself starts below)
    _check(device, info, stepper)
    n, period = stepper.n, int(round(1e9 * stepper.dt))
    ticks = int(round(seconds / stepper.dt))
    writer = None
    if record is not None:
        m = {
            "sample_rate_hz": f"{info.rate_hz:g}",
            "counts_per_rev": f"{info.counts_per_rev:g}",
            "command_hold": "zoh",
            "source": "manus run-hardware",
            "streamed": "true",
            **(meta or {}),
        }
        writer = RecordingWriter(record, columns(n, stepper.extras), m, flush_seconds=0.0)
    width = 1 + 2 * n + len(stepper.extras) + 8
    rows = np.zeros((LOG_EVERY, width))
    nrow = 0
    t_in = np.zeros(ticks + 1, np.int64)
    seqs = np.zeros(ticks + 1, np.int64)
    compute = np.zeros(ticks + 1, np.int64)
    late = np.zeros(ticks + 1, bool)
    q_log = np.zeros((ticks + 1, n))
    ref_log = np.zeros((ticks + 1, n))
    tau_log = np.zeros((ticks + 1, n))
    result = Result(recording=None if record is None else str(record))
    clock, tpv, vmax = time.perf_counter_ns, info.torque_per_volt, info.volt_limit
    i = 0
    gc.collect()  # everything is ready before the session starts: the device's watchdog runs from HELLO
    gc.disable()
    try:
        with _Stop() as stop, Realtime() if realtime else contextlib.nullcontext() as rt:
            blocking = rt is not None and rt.active
            if rt is not None:
                result.scheduling = rt.why + (" (waits by blocking)" if blocking else "")
            device.connect(spin=not blocking)
            sample = device.receive(clock() + int(FIRST_SAMPLE_TIMEOUT * 1e9), expect_ns=clock(), spin=not blocking)
            if sample is None:
                result.stopped_by, result.reason = "watchdog", "no first sample from the device"
                return result
            stepper.start(sample.counts)
            lim = stepper.limits
            limit = lim.torque
            seq0, offset = sample.seq, None
            q_prev, tau_prev, held, k_prev = sample.counts * stepper.q_step, np.zeros(n), np.zeros(n), 0
            # the loop's quality over the last `lim.window` ticks: late commands and lost samples
            late_ring, lost_ring = np.zeros(lim.window, bool), np.zeros(lim.window, np.int64)
            n_late = n_lost = 0
            while True:
                t0 = clock()
                k = (sample.seq - seq0) & 0xFFFFFFFF
                tau, extras, trip, clamped = stepper.step(k, sample.counts)
                # the limits again, here, on what the device sent and what was sent to it
                q = sample.counts * stepper.q_step
                code, joint, held = check(lim, q, q_prev, max(k - k_prev, 1), tau_prev, held)
                tau = tau.tolist()  # Python floats: a few µs less than numpy on 2 values
                if not all(map(math.isfinite, tau)):
                    trip = trip or NONFINITE
                trip = trip or int(code)  # the tick's own trip first, else the loop's
                if trip:
                    tau = [0.0] * n
                clamped = clamped or any(abs(x) > limit for x in tau)
                tau = [min(max(x, -limit), limit) for x in tau]  # the loop's own clamp, whatever the stepper did
                out = [min(max(x / tpv, -vmax), vmax) for x in tau] if volts else tau
                device.send(sample.seq, out, P.CMD_VOLTS if volts else 0)
                t1 = clock()
                transit = t0 - sample.time_ns
                offset = transit if offset is None or transit < offset else offset
                t_in[i], seqs[i], compute[i] = t0, k, t1 - t0
                latency = t1 - (sample.time_ns + offset)
                late[i] = latency > period
                slot, lost_now = i % lim.window, max(k - k_prev - 1, 0)
                n_late += int(late[i]) - int(late_ring[slot])
                n_lost += lost_now - int(lost_ring[slot])
                late_ring[slot], lost_ring[slot] = late[i], lost_now
                starved = n_late > lim.missed * lim.window or n_lost > lim.lost * lim.window
                if starved and not trip:
                    trip = LOOP
                result.device_late += bool(sample.flags & P.STATUS_LATE)
                q_log[i], tau_log[i], ref_log[i] = q, tau, extras[:n]
                prev = t_in[i - 1] if i and seqs[i - 1] == k - 1 else t0 - period
                rows[nrow] = np.concatenate(
                    [
                        [k * stepper.dt],
                        q,
                        tau,
                        extras,
                        [(t1 - t0) / 1e3, (t0 - prev) / 1e3, latency / 1e3, late[i], sample.flags, sample.seq],
                        [clamped, trip],
                    ]
                )
                nrow += 1
                i += 1
                if nrow == LOG_EVERY:
                    if writer is not None:
                        writer.append(rows)
                    nrow = 0
                if trip == LOOP:
                    result.stopped_by = "limit"
                    result.reason = (
                        f"loop quality at tick {k}: of the last {lim.window} ticks, {n_late} commands late and "
                        f"{n_lost} samples lost (limits: {lim.missed:.0%}, {lim.lost:.0%}) (zero torque sent)"
                    )
                    break
                if trip:
                    ticks_seen = max(k - k_prev, 1)
                    why = reason(trip, int(joint), lim, q, q_prev, ticks_seen, k * stepper.dt)
                    by = "" if trip in (code, NONFINITE) else " (found by the compiled tick)"
                    result.stopped_by = "fault" if trip == NONFINITE else "limit"
                    result.reason = f"{why} at tick {k}{by} (zero torque sent)"
                    break
                q_prev, tau_prev, k_prev = q, np.asarray(tau), k
                if sample.flags & P.STATUS_FAULT:
                    result.stopped_by, result.reason = "fault", "the device reports a fault (it refused a command)"
                    break
                if sample.flags & P.STATUS_WATCHDOG:
                    result.stopped_by, result.reason = (
                        "watchdog",
                        "the device's watchdog fired (a command came too late)",
                    )
                    break
                if stop.requested:
                    result.stopped_by, result.reason = "user", "interrupted"
                    break
                if k >= ticks - 1 or i > ticks:
                    break
                sample = device.receive(
                    t0 + int(watchdog * 1e9), expect_ns=t0 + period, idle=stepper.keep_warm, spin=not blocking
                )
                if sample is None:
                    result.stopped_by = "watchdog"
                    result.reason = f"no sample from the device for {watchdog * 1e3:g} ms"
                    break
    finally:
        gc.enable()
        device.stop()
        if writer is not None:
            if nrow:
                writer.append(rows[:nrow])
            writer.close({"stopped_by": result.stopped_by, "reason": result.reason})
    return _summary(
        result, device, period, t_in[:i], seqs[:i], compute[:i], late[:i], q_log[:i], ref_log[:i], tau_log[:i]
    )


def _check(device, info, stepper) -> None:
    where = device.url
    if info.n_joints != stepper.n:
        device.stop()
        raise ManusError(f"{where}: the device has {info.n_joints} joint(s), the controller {stepper.n}")
    if abs(info.rate_hz * stepper.dt - 1) > 1e-6:
        device.stop()
        raise ManusError(
            f"{where}: the device samples at {info.rate_hz:g} Hz, the controller runs at {1 / stepper.dt:g} Hz"
        )


def _summary(result, device, period, t_in, seqs, compute, late, q, ref, tau) -> Result:
    result.ticks = int(t_in.size)
    result.deadline_misses = int(late.sum())
    result.compute_us = percentiles(compute / 1e3)
    consecutive = np.diff(seqs) == 1
    result.jitter_us = percentiles(np.abs(np.diff(t_in)[consecutive] - period) / 1e3)
    result.lost_samples = int(np.sum(np.diff(seqs) - 1)) if seqs.size > 1 else 0
    result.refused = dict(device.refused)
    if q.size:
        result.tracking_rms = np.sqrt(np.mean((q - ref) ** 2, axis=0)).round(6).tolist()
        result.max_abs_tau = np.abs(tau).max(axis=0).round(4).tolist()
    return result


def report(r: dict) -> str:
    """The figures of a run, as printed at its end."""
    c, j = r["compute_us"], r["jitter_us"]
    lines = [
        f"stopped by {r['stopped_by']}" + (f": {r['reason']}" if r.get("reason") else ""),
        f"  ticks {r['ticks']}, deadline misses {r['deadline_misses']}, lost samples {r['lost_samples']}",
        f"  compute µs  p50 {c['p50']}  p99 {c['p99']}  max {c['max']}",
        f"  jitter  µs  p50 {j['p50']}  p99 {j['p99']}  max {j['max']}",
    ]
    if r.get("refused"):
        lines.append("  refused packets: " + ", ".join(f"{k} {v}" for k, v in sorted(r["refused"].items())))
    if r.get("tracking_rms"):
        lines.append("  tracking error RMS per joint [rad]: " + ", ".join(f"{x:.5f}" for x in r["tracking_rms"]))
    if r.get("recording"):
        lines.append(f"  recording: {r['recording']}")
    return "\n".join(lines)
