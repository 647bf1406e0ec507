"""The hardware loop against the rig emulator on loopback: a run that tracks its reference and
leaves a readable recording, and faults (the emulator stopping, lost and garbage packets, a
controller returning NaN, Ctrl-C, kill -9 of the loop) that each end at zero torque with what was
recorded still readable. No timing asserts: those figures belong to `manus bench hardware`."""

import os
import re
import signal
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import IO, cast

import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants import protocol as P
from manus.plants.hardware import realtime_jax

realtime_jax()

from manus.plants.device import UdpDevice, open_device  # noqa: E402
from manus.plants.hardware import LOG_EVERY, CompiledTick, run_loop  # noqa: E402
from manus.plants.limits import Limits  # noqa: E402
from manus.plants.recording import RecordingWriter, read  # noqa: E402
from manus.plants.stepper import Controller, Plant  # noqa: E402

MANUS = [sys.executable, "-m", "manus.runs.cli"]
ROOT = Path(__file__).resolve().parents[2]
TRUTH = "rigid,viscous,coulomb"
HALF_LSB_TORQUE = 10.0 / 2**11 * 2.22 / 2  # the D/A's rounding, in N·m
# these runs test other things than the loop's quality, on a machine the test suite keeps busy: no
# share of late commands or lost samples stops them (tests/plants/test_loop_quality.py tests that)
UNJUDGED_LOOP = Limits(missed=1.0, lost=1.0)
STARVED = 0.02  # a run with more of its commands late than this share: its tracking is not judged


def _start_emulator(tmp: Path, name: str, *extra):
    log, err = tmp / f"{name}.csv", tmp / f"{name}.err"
    proc = subprocess.Popen(
        MANUS + ["emulate", "--port", "0", "--truth", TRUTH, "--log", str(log), "--watchdog-ms", "300", *extra],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=open(err, "w"),  # noqa: SIM115 (the emulator's, for as long as it runs)
    )
    return proc, log, err


def _port(proc, err: Path) -> int:
    end = time.monotonic() + 60
    while time.monotonic() < end:
        m = re.search(r"on udp://127\.0\.0\.1:(\d+)", err.read_text())
        if m:
            return int(m.group(1))
        assert proc.poll() is None, err.read_text()
        time.sleep(0.05)
    raise AssertionError("the emulator did not start")


def _stop(proc):
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture(scope="module")
def rigs(tmp_path_factory):
    """Two emulators, started together: a clean one, and one that loses 5 % of the packets each
    way and sends junk datagrams."""
    tmp = tmp_path_factory.mktemp("rigs")
    clean = _start_emulator(tmp, "clean")
    lossy = _start_emulator(tmp, "lossy", "--drop", "0.05", "--garbage", "0.05", "--seed", "3")
    try:
        yield {name: (proc, _port(proc, err), log) for name, (proc, log, err) in (("clean", clean), ("lossy", lossy))}
    finally:
        for proc, *_ in (clean, lossy):
            _stop(proc)


@pytest.fixture(scope="module")
def stepper(rigs):
    from manus.adaptive.controllers import compiled_tick

    dev = open_device(f"udp://127.0.0.1:{rigs['clean'][1]}")
    info = dev.connect()
    dev.stop()
    dev.close()
    return compiled_tick(info, "slotine-li", "kalman_cv", TRUTH, None, "benign", UNJUDGED_LOOP)


def _device(rigs, name) -> UdpDevice:
    dev = cast(UdpDevice, open_device(f"udp://127.0.0.1:{rigs[name][1]}"))
    dev.connect()
    dev.stop()
    return dev


def _session(log: Path, host_rec=()):
    """The device log and the rows of its last session, read once the session has ended (its
    last row flagged STOPPED or WATCHDOG: the emulator flushes its log then) or after 5 s."""
    deadline = time.monotonic() + 5
    while True:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            dev = read(log)
        rows = dev.extra["session"] == dev.extra["session"].max()
        ended = int(dev.extra["flags"][np.flatnonzero(rows)[-1]]) & (P.STATUS_STOPPED | P.STATUS_WATCHDOG)
        if (ended and rows.sum() >= len(host_rec)) or time.monotonic() > deadline:
            return dev, rows
        time.sleep(0.1)


def test_a_two_second_run_tracks_its_reference_and_leaves_a_readable_recording(rigs, stepper, tmp_path):
    dev = _device(rigs, "clean")
    r = run_loop(
        dev,
        stepper,
        2.0,
        tmp_path / "run.csv",
        watchdog=0.5,
        meta={"controller": "slotine-li", "structure": "manus2"},
        realtime=True,  # (as run-hardware runs it: the machine's other work, this suite's, delays it least)
    )
    dev.close()
    assert r.stopped_by == "end", r.reason
    assert r.ticks == 2000 and r.lost_samples == 0 and r.refused == {}
    rec = read(tmp_path / "run.csv")
    assert len(rec) == 2000 and rec.sample_rate_hz == 1000 and rec.counts_per_rev == 131072
    assert np.allclose(np.diff(rec.t), 1e-3)
    qref = np.stack([rec.extra["qref1"], rec.extra["qref2"]], 1)
    err = rec.q - qref
    # the benign trajectory swings 0.2 rad; the adaptive loop holds it within a few milliradians,
    # where its commands arrive in time (a machine that starves the loop, the device holding stale
    # commands, leaves the tracking unjudged; the rest is judged all the same)
    assert np.ptp(qref[:, 0]) > 0.15
    assert np.allclose(r.tracking_rms, np.sqrt(np.mean(err**2, 0)), atol=1e-6)
    if r.deadline_misses <= STARVED * r.ticks:
        assert np.max(np.abs(err)) < 5e-3, (np.max(np.abs(err)), r.deadline_misses, r.scheduling)
    assert np.all(np.abs(rec.tau) <= 22.2) and np.ptp(rec.tau[:, 0]) > 0.1
    # the encoder counts crossed the wire exactly: the device logged the same positions per sample
    dev_rec, rows = _session(rigs["clean"][2], rec)
    ticks = rows & ((dev_rec.extra["flags"].astype(int) & P.STATUS_STOPPED) == 0)  # not the final STOP row
    by_seq = {int(s): i for i, s in zip(np.flatnonzero(ticks), dev_rec.extra["seq"][ticks], strict=True)}
    idx = [by_seq[int(s)] for s in rec.extra["seq"]]
    assert np.array_equal(dev_rec.q[idx], rec.q)
    # the torque the device applied over the period after sample k is the command answering k
    # (through the 12-bit D/A), wherever that command arrived in time
    nxt = [by_seq.get(int(s) + 1) for s in rec.extra["seq"][:-1]]
    ok = np.array([j is not None and not int(dev_rec.extra["flags"][j]) & P.STATUS_LATE for j in nxt])
    applied = dev_rec.tau[[j for j, o in zip(nxt, ok, strict=True) if o and j is not None]]
    assert ok.any()
    assert np.max(np.abs(applied - rec.tau[:-1][ok])) <= HALF_LSB_TORQUE + 1e-6
    # and the session ended at zero torque
    assert np.all(dev_rec.tau[np.flatnonzero(rows)[-1]] == 0)


def test_the_real_time_loop_blocks_instead_of_spinning_and_restores_the_thread(rigs, stepper, tmp_path, monkeypatch):
    """`realtime=True`: the loop's thread under SCHED_FIFO where this machine allows it (else an
    ordinary process, said), waiting by blocking: the same run, and never a look at the socket
    that finds nothing followed by another look without a blocking wait or a warm call between
    (a spin), where the ordinary loop spins near every sample; the thread's scheduling is back as
    it was."""
    import select as select_module

    from manus.plants import device as device_module

    state = {"missed": False, "spins": 0}

    def waited(*args):
        state["missed"] = False
        return select_module.select(*args)

    def warm(keep_warm=stepper.keep_warm):
        state["missed"] = False
        keep_warm()

    monkeypatch.setattr(device_module, "select", type("Select", (), {"select": staticmethod(waited)}))
    monkeypatch.setattr(stepper, "keep_warm", warm)
    before = os.sched_getscheduler(0)
    spins = {}
    for realtime in (False, True):
        dev = _device(rigs, "clean")
        state["spins"] = 0

        def looked(packet=dev._packet):
            state["spins"] += state["missed"]
            got = packet()
            state["missed"] = got is None
            return got

        dev._packet = looked
        r = run_loop(dev, stepper, 1.0, tmp_path / f"rt{realtime}.csv", watchdog=0.5, realtime=realtime)
        dev.close()
        assert r.stopped_by == "end" and r.ticks == 1000, r.reason
        assert max(r.tracking_rms) < 5e-3
        spins[realtime] = (state["spins"], r.scheduling)
    assert os.sched_getscheduler(0) == before
    (spun, spun_how), (blocked, blocked_how) = spins[False], spins[True]
    assert "spinning" in spun_how
    assert "SCHED_FIFO priority 80" in blocked_how or "refused" in blocked_how
    assert blocked == 0 < spun, spins


def test_a_real_time_emulator_serves_a_real_time_loop(stepper, tmp_path):
    """`manus emulate --realtime` (SCHED_FIFO where allowed, blocking between its periods) plays
    the rig for a real-time loop: the run ends at its end, every sample answered."""
    proc, _, err = _start_emulator(tmp_path, "rt", "--realtime")
    try:
        dev = cast(UdpDevice, open_device(f"udp://127.0.0.1:{_port(proc, err)}"))
        r = run_loop(dev, stepper, 1.0, None, watchdog=0.5, realtime=True)
        dev.close()
    finally:
        _stop(proc)
    assert r.stopped_by == "end" and r.ticks == 1000 and r.lost_samples == 0, r.reason


def test_the_rig_as_a_plant_steps_like_the_simulator_would(rigs):
    from manus.plants.hardware import HardwarePlant

    plant = HardwarePlant(_device(rigs, "clean"), watchdog=0.5)
    assert isinstance(plant, Plant) and plant.params == {} and plant.dt == pytest.approx(1e-3)
    state, q0 = plant.reset()
    assert np.allclose(q0, [0.464, 2.409], atol=1e-4)  # the emulated arm starts at rest at the centre
    q_true, qd_true = plant.truth(state)  # the rig's truth is its encoder: no velocity
    assert np.array_equal(q_true, q0) and np.all(np.isnan(qd_true))
    q = q0
    for _ in range(100):  # a constant 1 N·m on joint 1: it turns positive, from rest
        state, q = plant.step(state, [1.0, 0.0])
    assert q[0] - q0[0] > 1e-3
    with pytest.raises(Exception, match="non-finite command"):
        plant.step(state, [np.nan, 0.0])
    dev_rec, rows = _session(rigs["clean"][2])
    assert np.all(dev_rec.tau[np.flatnonzero(rows)[-1]] == 0)
    applied = dev_rec.tau[rows][2:-1]  # the D/A's 1 N·m, once the first command arrived
    assert np.any(np.abs(applied[:, 0] - 1.0) <= HALF_LSB_TORQUE) and np.all(applied[:, 1] == 0)
    plant.device.close()


class NaNAfter(Controller):
    """A controller that goes wrong: its inner controller's command until tick `at`, then NaN."""

    inner: Controller
    at: int

    def init(self, q0):
        return self.inner.init(q0), jnp.array(0)

    def step(self, state, q, ref):
        inner, k = state
        inner, tau = self.inner.step(inner, q, ref)
        return (inner, k + 1), jnp.where(k >= self.at, jnp.nan, tau)


def test_a_controller_returning_nan_stops_the_run_at_zero_torque(rigs, tmp_path):
    from manus.adaptive.controllers import make_controller
    from manus.plants import Model, structure_named
    from manus.plants.references import Benign

    dev = _device(rigs, "clean")
    ctrl = NaNAfter(make_controller("impedance", Model(structure_named("manus2", 2), TRUTH), 1e-3), 300)
    info = cast(P.Info, dev.info)
    tick = CompiledTick(ctrl, Benign(), 1e-3, info.counts_per_rev, 2, UNJUDGED_LOOP, info.torque_limit)
    tick.warm_up()
    r = run_loop(dev, tick, 2.0, tmp_path / "nan.csv", watchdog=0.5)
    dev.close()
    assert r.stopped_by == "fault" and "non-finite" in r.reason
    assert r.ticks == 301
    rec = read(tmp_path / "nan.csv")
    assert len(rec) == 301 and np.all(np.isfinite(rec.tau))
    assert np.all(rec.tau[-1] == 0) and np.all(np.abs(rec.tau[:-1]).sum(1) > 0)
    dev_rec, rows = _session(rigs["clean"][2], rec)
    assert np.all(dev_rec.tau[np.flatnonzero(rows)[-1]] == 0)
    assert int(dev_rec.extra["flags"][np.flatnonzero(rows)[-1]]) & P.STATUS_STOPPED


def test_lost_and_garbage_packets_are_counted_and_the_run_goes_on(rigs, stepper, tmp_path):
    dev = _device(rigs, "lossy")
    r = run_loop(dev, stepper, 1.0, tmp_path / "lossy.csv", watchdog=0.5)
    dev.close()
    assert r.stopped_by == "end", r.reason
    # 5 % of the samples lost on the way (binomial: 50 ± 7 of 1000)
    assert 15 <= r.lost_samples <= 100
    # every sample up to the last one answered is either answered or lost; the loop ends at the
    # first sample at or past the 1000th, which is later when the 1000th itself was lost (p = 5 %)
    assert 1000 <= r.ticks + r.lost_samples <= 1003
    # junk datagrams (5 % of ticks): random bytes, flipped bits, another version, cut short
    assert set(r.refused) <= {"magic", "version", "length", "crc", "kind", "joints"}
    assert 15 <= sum(r.refused.values()) <= 100 and r.refused.get("crc", 0) > 0 and r.refused.get("version", 0) > 0
    rec = read(tmp_path / "lossy.csv")
    assert len(rec) == r.ticks
    steps = np.round(np.diff(rec.t) * 1000).astype(int)
    assert steps.min() == 1 and (steps - 1).sum() == r.lost_samples  # the gaps are the lost samples
    assert max(r.tracking_rms) < 5e-3


def after_ticks(path: Path, ticks: int, action, timeout: float = 20.0) -> threading.Thread:
    """Run `action` once the loop's recording holds `ticks` rows (it is flushed every 0.1 s):
    faults are injected into a running loop however long its start took on a loaded machine."""

    def wait():
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if path.exists() and path.read_text().count("\n") > ticks:
                break
            time.sleep(0.01)
        action()

    thread = threading.Thread(target=wait, daemon=True)
    thread.start()
    return thread


def test_the_emulator_stopping_mid_run_trips_both_watchdogs(rigs, stepper, tmp_path):
    proc, _, log = rigs["clean"]
    dev = _device(rigs, "clean")
    freeze = after_ticks(
        tmp_path / "frozen.csv",
        300,
        lambda: (os.kill(proc.pid, signal.SIGSTOP), time.sleep(1.0), os.kill(proc.pid, signal.SIGCONT)),
    )
    r = run_loop(dev, stepper, 3.0, tmp_path / "frozen.csv", watchdog=0.55)
    dev.close()
    freeze.join()
    time.sleep(1.2)
    assert r.stopped_by == "watchdog" and "no sample" in r.reason
    assert 50 < r.ticks < 1000
    assert len(read(tmp_path / "frozen.csv")) == r.ticks
    dev_rec, rows = _session(log)
    last = np.flatnonzero(rows)[-1]
    assert np.all(dev_rec.tau[last] == 0)  # resumed to find the host gone: zero torque


def test_ctrl_c_and_strangers(rigs, stepper, tmp_path):
    dev = _device(rigs, "clean")
    stranger = __import__("socket").socket(2, 2)

    def meddle():
        for _ in range(10):  # a valid sample, from the wrong address
            stranger.sendto(P.encode_sensor(10**6, 0, [0, 0]), dev.address)

    timers = [
        after_ticks(
            tmp_path / "user.csv", 200, lambda: (meddle(), time.sleep(0.5), os.kill(os.getpid(), signal.SIGINT))
        )
    ]
    r = run_loop(dev, stepper, 4.0, tmp_path / "user.csv", watchdog=0.5)
    for t in timers:
        t.join()
    dev.close()
    stranger.close()
    assert r.stopped_by == "user"
    assert r.refused.get("address") == 10
    assert 50 < r.ticks < 3900 and len(read(tmp_path / "user.csv")) == r.ticks
    dev_rec, rows = _session(rigs["clean"][2])
    assert np.all(dev_rec.tau[np.flatnonzero(rows)[-1]] == 0)


def test_kill_9_of_the_loop_leaves_the_device_at_zero_torque_and_a_readable_recording(rigs, tmp_path):
    _, port, log = rigs["clean"]
    rec_path = tmp_path / "killed.csv"
    rig = tmp_path / "rig.toml"
    rig.write_text("[limits]\nmissed = 1.0\nlost = 1.0\n")  # (UNJUDGED_LOOP)
    loop = subprocess.Popen(
        MANUS
        + [
            "run-hardware",
            "--rig",
            str(rig),
            "--device",
            f"udp://127.0.0.1:{port}",
            "--seconds",
            "30",
            "--record",
            str(rec_path),
            "--watchdog-ms",
            "500",
            "--model",
            TRUTH,
        ],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    try:
        end = time.monotonic() + 90
        while time.monotonic() < end and (not rec_path.exists() or rec_path.read_text().count("\n") < 600):
            assert loop.poll() is None, cast(IO[bytes], loop.stderr).read().decode()
            time.sleep(0.05)
        os.kill(loop.pid, signal.SIGKILL)
        loop.wait()
    finally:
        if loop.poll() is None:
            loop.kill()
            loop.wait()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a cut last line is dropped with a warning
        rec = read(rec_path)
    assert len(rec) >= 400 and np.allclose(np.diff(rec.t), 1e-3)
    time.sleep(1.0)  # the device's watchdog (300 ms) fires, and it streams on at zero torque
    dev_rec, rows = _session(log)
    idx = np.flatnonzero(rows)
    tripped = idx[(dev_rec.extra["flags"][idx].astype(int) & P.STATUS_WATCHDOG) > 0]
    assert tripped.size > 10 and np.all(dev_rec.tau[tripped] == 0)
    assert np.all(dev_rec.tau[idx[idx > tripped[0]]] == 0) and np.any(dev_rec.tau[idx[idx < tripped[0]]] != 0)
    # what the kill lost: the device held the last command it got (flag LATE) from the sample after
    # it until its watchdog fired; the recording ends at most LOG_EVERY samples (10 ms) before that,
    # and a line the kill cut mid-write
    late = (dev_rec.extra["flags"].astype(int) & P.STATUS_LATE) > 0
    first = int(np.flatnonzero(idx == tripped[0])[0])
    while first > 0 and late[idx[first - 1]]:
        first -= 1
    last_answered = int(dev_rec.extra["seq"][idx[first]]) - 1
    assert 0 <= last_answered - int(rec.extra["seq"][-1]) <= LOG_EVERY + 1, (last_answered, rec.extra["seq"][-1])


def test_a_streamed_recording_cut_mid_number_drops_its_last_line(tmp_path):
    path = tmp_path / "cut.csv"
    with RecordingWriter(path, ["t", "q1", "tau1"], {"sample_rate_hz": "1000", "streamed": "true"}) as w:
        w.append(np.array([[0.0, 0.4183, 1.0], [0.001, 0.4184, 1.5], [0.002, 0.4185, 2.25]]))
    text = path.read_text()
    path.write_text(text[:-3])  # "...,2.25\n" -> "...,2." : parses, but is cut short
    with pytest.warns(UserWarning, match=r"cut.csv:6: incomplete last line dropped"):
        rec = read(path)
    assert rec.tau[:, 0].tolist() == [1.0, 1.5]
    # a hand-written file without a final newline keeps its last row
    plain = tmp_path / "plain.csv"
    plain.write_text("t,q1,tau1\n0,0.1,1\n0.001,0.2,2")
    assert read(plain).tau[:, 0].tolist() == [1.0, 2.0]
    # a cut that leaves a malformed row is dropped in any file
    plain.write_text("t,q1,tau1\n0,0.1,1\n0.001,0.2,2\n0.002,0.")
    with pytest.warns(UserWarning, match="incomplete last line"):
        assert len(read(plain)) == 2
