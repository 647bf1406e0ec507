"""Each fault the emulator injects (`--fault`), met by the hardware loop with the rig's limits: a
runaway, a stall, a broken encoder line and late samples each end in a zero-torque stop naming its
reason, on the sample the rule says (within 2 ms of the limit's crossing), the device left at zero
torque and the recording holding the reason; an INFO that cannot be true is refused before any
command."""

import dataclasses
import threading
from pathlib import Path

import numpy as np
import pytest

from manus.plants.hardware import realtime_jax

realtime_jax()

from manus.adaptive.controllers import compiled_tick  # noqa: E402
from manus.plants.device import DeviceError, UdpDevice  # noqa: E402
from manus.plants.hardware import run_loop  # noqa: E402
from manus.plants.limits import JUMP, LOOP, STALL, VELOCITY, Limits  # noqa: E402
from manus.plants.recording import read  # noqa: E402
from tests.plants.test_emulator_faults import TRUTH, _columns, _emulator  # noqa: E402

pytestmark = pytest.mark.slow  # real-time sessions

ONSET_S = 0.5
# (the emulator shares this process: its lateness is not the test)
UNJUDGED_LOOP = dataclasses.replace(Limits(), missed=1.0, lost=1.0)


def _run(tmp_path: Path, fault: str, limits: Limits, seconds: float = 3.0):
    emu = _emulator(tmp_path, fault, ONSET_S)
    tick = compiled_tick(emu.info, "slotine-li", "kalman_cv", TRUTH, None, "benign", limits)  # (compiled first)
    thread = threading.Thread(target=emu.serve, args=(seconds + 1.5,), daemon=True)
    thread.start()
    dev = UdpDevice("127.0.0.1", emu.port)
    try:
        r = run_loop(dev, tick, seconds, tmp_path / "host.csv", watchdog=0.5)
    finally:
        dev.close()
        thread.join(seconds + 5)
    log = _columns(tmp_path / "device.csv")
    return r, read(tmp_path / "host.csv"), log


@pytest.mark.parametrize(
    "fault, limits, code, words",
    [
        ("runaway", UNJUDGED_LOOP, VELOCITY, "velocity limit: joint 1"),
        ("stall", dataclasses.replace(UNJUDGED_LOOP, torque=1.0, stall_seconds=0.2), STALL, "stall: joint"),
        ("jump", UNJUDGED_LOOP, JUMP, "encoder jump: joint 1"),
        ("late", dataclasses.replace(Limits(), missed=0.5, window=0.2, lost=1.0), LOOP, "loop quality"),
    ],
)
def test_each_fault_ends_in_a_zero_torque_stop_that_names_it(tmp_path, fault, limits, code, words):
    r, host, device = _run(tmp_path, fault, limits)
    faulty = np.flatnonzero(device["fault"] == 1)
    raw = _columns(tmp_path / "host.csv")  # (as written: `read` leaves an encoder jump's row out, and says so)
    if not faulty.size or int(raw["seq"][-1]) < int(device["seq"][faulty[0]]):
        # the loop ended before the fault began: a machine busy enough to starve a 1 kHz loop (its quality
        # stop, `late`'s own limit, or the watchdog) leaves nothing to judge
        pytest.skip(f"the run ended before the fault's onset: {r.stopped_by}: {r.reason}")
    assert r.stopped_by == "limit" and words in r.reason, r.reason
    assert raw["trip"][-1] == code and np.all(raw["trip"][:-1] == 0) and host.meta["reason"] == r.reason
    assert len(host) == len(raw["t"]) - (fault == "jump")
    last = int(raw["seq"][-1])  # the sample the trip answered
    onset = int(device["seq"][faulty[0]])
    assert onset == round(ONSET_S / 1e-3)  # (the device's own clock: its samples)
    q = device["q1"]
    if fault == "runaway":  # the first sample (device side) whose speed over one period is over the limit
        speed = np.abs(np.diff(q)) / 1e-3
        over = int(device["seq"][1:][speed > limits.velocity][0])
        assert over <= last <= over + 2, (over, last)
    elif fault == "jump":
        assert last == onset
    elif fault == "stall":  # held at the limit from the onset on: 0.2 s later at the soonest
        assert onset + 200 <= last <= onset + 2500, (onset, last)
    else:  # half of a 200-tick window late: 100 ticks after the onset at most (fewer where some were late before)
        assert onset < last <= onset + 101, (onset, last)
    # the device ends the session at zero torque
    ended = np.flatnonzero(device["seq"] >= last)
    assert np.all(device["tau1"][ended[-1:]] == 0) and np.all(device["tau2"][ended[-1:]] == 0)


def test_a_device_that_reports_an_infinite_volt_limit_is_refused(tmp_path):
    emu = _emulator(tmp_path, "bad-info", 0.0)
    thread = threading.Thread(target=emu.serve, args=(2.0,), daemon=True)
    thread.start()
    dev = UdpDevice("127.0.0.1", emu.port)
    try:
        with pytest.raises(DeviceError, match=r"volt_limit = inf .*refusing to drive it"):
            dev.connect()
    finally:
        dev.close()
        thread.join(5)
