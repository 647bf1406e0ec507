"""The emulator's injected faults, seen by a scripted host on loopback: each fault's physical
signature in the samples it receives (runaway: joint 1 accelerates at the D/A's full torque over
the arm's inertia; stall: counts frozen under a large command; jump: INT32_MAX counts; bad-info:
an infinite volt limit; late: samples arriving 3 ms after their stamps), and the device log's
`fault` column marking the onset. The emulator runs in a thread of this process (sleeping, not
spinning, between its ticks); `bad-info` runs it as `manus emulate`, the command's flags included."""

import math
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest

from manus.plants.hardware import realtime_jax

realtime_jax()

from manus.plants import Model, Simulator, structure_named  # noqa: E402
from manus.plants import protocol as P  # noqa: E402
from manus.plants.device import UdpDevice  # noqa: E402
from manus.plants.emulator import INT32_MAX, LATE_NS, Emulator  # noqa: E402
from manus.plants.errors import ManusError  # noqa: E402

pytestmark = pytest.mark.slow  # real-time sessions

MANUS = [sys.executable, "-m", "manus.runs.cli"]
ROOT = Path(__file__).resolve().parents[2]
TRUTH = "rigid,viscous,coulomb"
T = 1e-3  # the emulated rig's period [s]
TAU_MAX = 2047 * (20 / 2**12) * 0.6 * 3.7  # the thesis D/A's largest code (12 bits, ±10 V), in N·m
STEP = 2 * math.pi / 131072  # the encoder's step [rad]


class Session(NamedTuple):
    info: P.Info
    seq: np.ndarray  # (k,) the samples received
    stamp: np.ndarray  # (k,) their device time [ns]
    arrival: np.ndarray  # (k,) when they arrived (same clock) [ns]
    counts: np.ndarray  # (k, n)
    log: dict[str, np.ndarray]  # the device's log of the session, by column
    onset: int  # the seq of the first sample the log marks `fault`


def _emulator(tmp_path: Path, fault: str, fault_at: float, structure="manus2", params=None) -> Emulator:
    sim = Simulator(Model(structure_named(structure, 2), TRUTH), params)
    return Emulator(sim, 0, watchdog=0.3, log=tmp_path / "device.csv", spin=0.0, fault=fault, fault_at=fault_at)


def _session(emu: Emulator, log_path: Path, seconds: float, command) -> Session:
    """A host answering each sample with `command(counts)` [N·m] for `seconds` of samples, then
    CMD_STOP; the emulator serves in a thread for `seconds` + 1.5 s, then closes its log."""
    thread = threading.Thread(target=emu.serve, args=(seconds + 1.5,), daemon=True)
    thread.start()
    dev = UdpDevice("127.0.0.1", emu.port)
    rows = []
    try:
        info = dev.connect(timeout=5.0)
        while True:
            s = dev.receive(time.perf_counter_ns() + 500_000_000)
            arrival = time.perf_counter_ns()
            assert s is not None, "the emulator stopped streaming"
            rows.append((s.seq, s.time_ns, arrival, *s.counts.astype(np.int64)))
            dev.send(s.seq, command(s.counts))
            if s.seq * T >= seconds:
                break
        dev.stop()
    finally:
        dev.close()
        thread.join(30)
    assert not thread.is_alive()
    a = np.array(rows, np.int64)
    log = _columns(log_path)
    on = np.flatnonzero(log["fault"] == 1)
    assert on.size, "the log marks no sample as faulty"
    return Session(info, a[:, 0], a[:, 1], a[:, 2], a[:, 3:], log, int(log["seq"][on[0]]))


def _columns(path: Path) -> dict[str, np.ndarray]:
    """The device log's columns, as written (`read` would refuse a `jump` log: its encoder glitches)."""
    lines = [line for line in path.read_text().splitlines() if line and not line.startswith("#")]
    values = np.array([[float(x) for x in line.split(",")] for line in lines[1:]])
    return dict(zip(lines[0].split(","), values.T, strict=True))


def _check_onset(s: Session, fault_at: float) -> np.ndarray:
    """The log's `fault` column: 0 before the sample taken `fault_at` into the session by the
    device's clock (seq ⌈fault_at / T⌉), 1 from it to the session's end. -> whether each received
    sample is at or past the onset."""
    fault, seq = s.log["fault"], s.log["seq"]
    first = np.flatnonzero(fault == 1)[0]
    assert seq[first] == math.ceil(fault_at / T - 1e-9)
    assert np.all(fault[:first] == 0) and np.all(fault[first:] == 1)
    assert np.all(np.diff(seq[:-1]) == 1)  # every period logged (the last row: the STOP, same seq)
    return s.seq >= s.onset


def test_runaway_accelerates_joint_1_at_the_full_torque_over_its_inertia(tmp_path):
    # two independent axes (joint 1: 0.15 kg m², the thesis's joint-1 friction): a closed form
    emu = _emulator(tmp_path, "runaway", 0.15, "axis", {"M1": 0.15, "b1": 0.222, "Fc1": 0.099})
    p = {k: float(v) for k, v in emu.sim.params.items()}
    s = _session(emu, tmp_path / "device.csv", 0.5, lambda c: np.zeros(2))
    on = _check_onset(s, 0.15)
    q = s.counts * STEP
    assert np.all(s.counts[~on] == 0) and np.all(s.counts[:, 1] == 0)  # at rest, then joint 2 as commanded
    # sample onset + k has felt the full torque for k + 1 periods: J v' = τ − b v − Fc (v > 0)
    J, b, fc = p["M1"], p["b1"], p["Fc1"]
    t = (s.seq[on] - s.onset + 1) * T
    v_inf, tc = (TAU_MAX - fc) / b, J / b
    expected = v_inf * (t - tc * (1 - np.exp(-t / tc)))
    assert np.allclose(q[on, 0], expected, rtol=2e-3, atol=5 * STEP)
    # velocity from the counts (central differences over 5 ms): bounded by the frictionless motion
    # above and by the largest friction (at the velocity reached) below
    assert np.all(np.diff(s.seq) == 1)  # no sample lost on loopback
    k = np.flatnonzero(on)[5:-5]
    v = (q[k + 5, 0] - q[k - 5, 0]) / (10 * T)
    tk = (s.seq[k] - s.onset + 1) * T
    assert np.all(v <= TAU_MAX * tk / J + 1e-3)
    assert np.all(v >= (TAU_MAX - fc - b * v) * tk / J - 1e-3)
    assert v[tk <= 0.3].max() > 20  # a runaway: past 20 rad/s within 0.3 s under zero command
    # the log: joint 1 driven at the D/A's largest code from the onset, zero torque once stopped
    log = s.log
    rows = log["fault"] == 1
    assert np.allclose(log["tau1"][rows][:-1], TAU_MAX, atol=1e-9) and np.all(log["tau2"] == 0)
    assert np.all(log["tau1"][~rows] == 0) and log["tau1"][-1] == 0


def test_stall_freezes_the_counts_whatever_the_torque(tmp_path):
    emu = _emulator(tmp_path, "stall", 0.15)
    s = _session(emu, tmp_path / "device.csv", 0.4, lambda c: np.array([10.0, -10.0]))
    on = _check_onset(s, 0.15)
    before, after = s.counts[~on], s.counts[on]
    assert np.ptp(before[:, 0]) > 1000 and np.ptp(before[:, 1]) > 1000  # the commanded torque moved the arm
    assert np.all(after == after[0]) and np.array_equal(after[0], before[-1])  # held where it was at the onset
    log = s.log
    rows = log["fault"] == 1
    assert np.all(log["qd1"][rows] == 0) and np.all(log["qd2"][rows] == 0)
    for j, sign in ((1, 1), (2, -1)):  # the motors still push (the D/A's step: 11 mN·m)
        assert np.allclose(log[f"tau{j}"][rows][:-1], 10.0 * sign, atol=0.006)


def test_jump_reports_int32_max_on_joint_1_while_the_arm_moves_on(tmp_path):
    emu = _emulator(tmp_path, "jump", 0.1)
    s = _session(emu, tmp_path / "device.csv", 0.3, lambda c: np.array([1.0, 1.0]))
    on = _check_onset(s, 0.1)
    assert np.all(s.counts[on, 0] == INT32_MAX) and np.all(np.abs(s.counts[~on, 0]) < 131072)
    assert np.all(np.diff(s.counts[on, 1]) != 0)  # joint 2's encoder: the arm still moves
    log = s.log
    rows = log["fault"] == 1
    assert np.allclose(log["q1"][rows], INT32_MAX * STEP, rtol=1e-11)
    assert np.all(np.diff(log["qd1"][rows][:-1]) > 0)  # the true velocity keeps growing under the command


def test_jump_encodes_int32_max_exactly():
    packet = P.encode_sensor(7, 123, np.array([INT32_MAX, -5], np.int64))
    decoded = P.decode(packet)
    assert isinstance(decoded, P.Sensor) and decoded.counts.tolist() == [2**31 - 1, -5]
    assert packet[P.size(P.SENSOR, 2) - 12 : P.size(P.SENSOR, 2) - 8] == b"\xff\xff\xff\x7f"


def test_late_samples_arrive_3_ms_after_their_stamps(tmp_path):
    emu = _emulator(tmp_path, "late", 0.15)
    s = _session(emu, tmp_path / "device.csv", 0.5, lambda c: np.zeros(2))
    on = _check_onset(s, 0.15)
    delay = (s.arrival - s.stamp) / 1e6  # ms, one clock (CLOCK_MONOTONIC)
    assert np.all(delay[on] >= LATE_NS / 1e6)  # held back at least 3 ms, by construction
    shift = np.median(delay[on]) - np.median(delay[~on])
    assert np.median(delay[~on]) < 2.0 and 2.5 <= shift <= 8.0, (np.median(delay[~on]), shift)
    # the commands answering them cannot be in time: the device holds the last one (LATE)
    log = s.log
    rows = np.flatnonzero(log["fault"] == 1)[1:-1]
    late = (log["flags"][rows].astype(int) & P.STATUS_LATE) > 0
    assert late.mean() > 0.9


def test_bad_info_reports_an_infinite_volt_limit_through_manus_emulate(tmp_path):
    log, err = tmp_path / "device.csv", tmp_path / "err.txt"
    proc = subprocess.Popen(
        MANUS + ["emulate", "--port", "0", "--fault", "bad-info", "--log", str(log), "--watchdog-ms", "300"],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=open(err, "w"),  # noqa: SIM115 (the emulator's, for as long as it runs)
    )
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.settimeout(5.0)
    try:
        end = time.monotonic() + 60
        while not (m := re.search(r"on udp://127\.0\.0\.1:(\d+), fault bad-info", err.read_text())):
            assert proc.poll() is None and time.monotonic() < end, err.read_text()
            time.sleep(0.05)
        device = ("127.0.0.1", int(m.group(1)))
        # a host of its own (manus's refuses this INFO): HELLO, then the INFO as sent
        sock.sendto(P.encode_hello(1, 0, 1), device)
        info = P.decode(sock.recv(2048))
        assert isinstance(info, P.Info) and info.volt_limit == math.inf
        assert (info.n_joints, info.rate_hz, info.counts_per_rev) == (2, 1000.0, 131072.0)
        assert info.torque_per_volt == pytest.approx(0.6 * 3.7, abs=1e-12)
        for seq in range(2, 52):  # 1000 N·m answering 50 samples: the D/A keeps its true range
            sample = P.decode(sock.recv(2048))
            assert isinstance(sample, P.Sensor)
            sock.sendto(P.encode_command(seq, 0, sample.seq, [1000.0, 0.0]), device)
        sock.sendto(P.encode_command(52, 0, 0, [0.0, 0.0], P.CMD_STOP), device)
    finally:
        sock.close()
        proc.terminate()
        proc.wait(20)
    rec = _columns(log)
    assert np.all(rec["fault"] == 1)  # on from the session's start: the INFO is the fault
    assert rec["tau1"].max() == pytest.approx(TAU_MAX, abs=1e-9) and np.all(rec["tau2"] == 0)


def test_an_unknown_fault_or_onset_is_a_one_line_error(tmp_path):
    sim = Simulator(Model(structure_named("manus2", 2), TRUTH))
    with pytest.raises(
        ManusError, match=r"unknown fault 'smoke': the emulator plays runaway, stall, jump, bad-info, late"
    ):
        Emulator(sim, 0, fault="smoke")
    for at in (-0.1, math.nan, math.inf):
        with pytest.raises(ManusError, match="fault_at is seconds after the session starts"):
            Emulator(sim, 0, fault="stall", fault_at=at)
    r = subprocess.run(
        MANUS + ["emulate", "--port", "0", "--fault", "late", "--fault-at", "-1"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert r.returncode == 2 and r.stderr.strip().count("\n") == 0 and "--fault-at -1" in r.stderr, r.stderr
