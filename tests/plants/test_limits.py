"""The rig's limits (manus.plants.limits) and the hardware loop that enforces them: the rule
checked against hand-worked cases, the same in numpy and in JAX; a rig file read and refused; and
the loop (its compiled tick and, again, the loop itself) against a scripted device whose arm runs
away, jumps, leaves its workspace or stalls: each ends at zero torque, latched, on the first tick
the rule says, the reason named in the result and in the recording."""

import dataclasses
import math

import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants import protocol as P
from manus.plants.device import Device
from manus.plants.errors import ManusError, RecordingNote
from manus.plants.hardware import CompiledTick, run_loop
from manus.plants.limits import JUMP, LOOP, STALL, STALL_SHARE, VELOCITY, WORKSPACE, Limits, check
from manus.plants.recording import read
from manus.plants.references import CENTRE, Benign
from manus.plants.stepper import Controller

DT = 1e-3
CPR = 131072
STEP = 2 * math.pi / CPR
INFO = P.Info(2, 1000.0, CPR, 2.22, 10.0)  # the emulator's: a 10 V D/A at 2.22 N·m/V


def _lim(**kw):
    return Limits(**kw).resolved(2, np.array(CENTRE), INFO.torque_limit, DT)


# -- the rule ------------------------------------------------------------------------------------


def test_the_rule_on_hand_worked_ticks():
    lim = _lim()
    q0 = np.array(CENTRE)
    zero, none = np.zeros(2), np.zeros(2)
    # 3.9 rad/s on joint 2 passes; 4.1 trips it (velocity, joint 2)
    assert check(lim, q0 + [0, 3.9e-3], q0, 1, zero, none)[0] == 0
    code, joint, _ = check(lim, q0 + [0, 4.1e-3], q0, 1, zero, none)
    assert (code, joint) == (VELOCITY, 1)
    # after 2 lost samples the same move is over 3 periods: 1.37 rad/s, no trip
    assert check(lim, q0 + [0, 4.1e-3], q0, 3, zero, none)[0] == 0
    # a move of 0.2 rad in one tick is a jump, named before the speed it also is
    assert check(lim, q0 + [0.2, 0], q0, 1, zero, none)[:2] == (JUMP, 0)
    # the workspace: the start ± 1 rad
    assert check(lim, q0 + [0, 1.0005], q0 + [0, 0.9999], 1, zero, none)[:2] == (WORKSPACE, 1)
    # the stall: held at ≥ 95 % of the torque limit, slower than 0.05 rad/s, for 0.5 s
    push = np.array([STALL_SHARE * lim.torque, 0.0])
    held = np.array([0.499, 0.3])
    code, joint, held_now = check(lim, q0, q0, 1, push, held)
    assert (code, joint) == (STALL, 0) and held_now == pytest.approx([0.5, 0.0])
    code, _, held_now = check(lim, q0 + [1e-4, 0], q0, 1, push, np.array([0.2, 0]))  # 0.1 rad/s: moving
    assert code == 0 and held_now[0] == 0


def test_the_rule_is_the_same_in_numpy_and_in_jax():
    lim = _lim(velocity=2.0, jump=0.05, stall_seconds=0.01)
    rng = np.random.default_rng(0)
    for _ in range(300):
        q_prev = np.array(CENTRE) + rng.normal(0, 0.6, 2)
        q = q_prev + rng.normal(0, 3e-3, 2) * rng.choice([1, 10, 30], 2)
        tau = rng.choice([0.0, 6.9, -7.0], 2)
        held = rng.uniform(0, 0.012, 2)
        ticks = int(rng.integers(1, 3))
        a = check(lim, q, q_prev, ticks, tau, held)
        b = check(lim, jnp.asarray(q), jnp.asarray(q_prev), ticks, jnp.asarray(tau), jnp.asarray(held), jnp)
        assert int(a[0]) == int(b[0]) and (int(a[0]) == 0 or int(a[1]) == int(b[1]))
        np.testing.assert_allclose(a[2], np.asarray(b[2]), rtol=1e-12)


def test_limits_are_checked_and_a_rig_file_is_read_or_refused(tmp_path):
    for name, bad in (("torque", 0.0), ("velocity", math.inf), ("jump", -1.0), ("stall_seconds", float("nan"))):
        with pytest.raises(ManusError, match=name):
            dataclasses.replace(Limits(), **{name: bad})
    with pytest.raises(ManusError, match="low and high"):
        Limits(low=(0.0, 0.0))
    with pytest.raises(ManusError, match="under high"):
        Limits(low=(0.0, 1.0), high=(1.0, 0.5))
    rig = tmp_path / "rig.toml"
    rig.write_text("[limits]\ntorque = 3.5\nlow = [-0.5, 1.4]\nhigh = [1.5, 3.4]\n")
    lim = Limits.read(rig)
    assert lim.torque == 3.5 and lim.velocity == Limits().velocity and lim.low == (-0.5, 1.4)
    r = lim.resolved(2, np.zeros(2), INFO.torque_limit, DT)
    assert r.torque == 3.5 and list(r.low) == [-0.5, 1.4]
    # the device's own limit where it is smaller; never the device's alone (an infinite D/A)
    assert Limits(torque=50).resolved(2, np.zeros(2), 22.2, DT).torque == 22.2
    assert Limits().resolved(2, np.zeros(2), math.inf, DT).torque == Limits().torque
    for text, words in (
        ("[limits]\ntorque = 3.5\nspeed = 2\n", "unknown limit(s) speed"),
        ("torque = 3\n", "no [limits] table"),
        ("[limits]\ntorque = 'big'\n", "torque must be a positive finite number"),
        ("[limits\n", "not a readable TOML"),
        ("[limits]\nlow = [0.0]\nhigh = [1.0]\n", None),
    ):
        rig.write_text(text)
        if words is None:
            with pytest.raises(ManusError, match="a workspace of 1 joint"):
                Limits.read(rig).resolved(2, np.zeros(2), 22.2, DT)
            continue
        with pytest.raises(ManusError, match=words.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")):
            Limits.read(rig)
    with pytest.raises(ManusError, match="no such rig file"):
        Limits.read(tmp_path / "missing.toml")


def test_a_device_description_that_cannot_be_true_is_named():
    assert INFO.problem() == ""
    for field, value in (("rate_hz", 0.0), ("counts_per_rev", 0.0), ("torque_per_volt", 0.0), ("volt_limit", math.inf)):
        assert field in INFO._replace(**{field: value}).problem()
    assert "joints" in INFO._replace(n_joints=0).problem()


# -- the loop against a scripted rig -------------------------------------------------------------


class Scripted(Device):
    """A 2-joint rig whose encoder reads `script(k)` [rad] at sample k (no physics): samples come
    at once, stamped now (`age(k)` [s] earlier: a late sample), `skip(k)` samples lost before
    sample k; what the host sends is kept."""

    url = "scripted://"

    def __init__(self, script, age=lambda k: 0.0, skip=lambda k: 0):
        super().__init__()
        self.script, self.k, self.commands = script, 0, []
        self.age, self.skip = age, skip

    def connect(self, timeout: float = 2.0, spin: bool = True) -> P.Info:
        self.info, self.k = INFO, 0
        return INFO

    def receive(self, deadline_ns, expect_ns=None, idle=None, spin=True):
        import time

        self.k += self.skip(self.k)
        counts = np.clip(np.round(np.asarray(self.script(self.k), float) / STEP), -(2**31), 2**31 - 1)
        sample = P.Sensor(self.k, time.perf_counter_ns() - int(self.age(self.k) * 1e9), counts.astype(np.int64), 0)
        self.k += 1
        return sample

    def send(self, ack, values, flags=0) -> None:
        if not flags & P.CMD_STOP:
            self.commands.append((ack, np.asarray(values, float) * INFO.torque_per_volt))

    def close(self) -> None:
        pass


class Push(Controller):
    """Commands 100 N·m on joint 1, whatever happens (the clamp holds it at the limit)."""

    def init(self, q0):
        return jnp.zeros(())

    def step(self, state, q, ref):
        return state, jnp.array([100.0, 0.0])


def _tick(controller=None, limits=None):
    from manus.adaptive.controllers import make_controller
    from manus.plants import Model, structure_named

    c = controller or make_controller("impedance", Model(structure_named("manus2", 2), "rigid"), DT)
    tick = CompiledTick(c, Benign(), DT, CPR, 2, limits, INFO.torque_limit)
    tick.warm_up()
    return tick


ONSET = 200


@pytest.mark.parametrize(
    "fault, script, code, first",
    [
        # joint 1 accelerates at 1000 rad/s² from the onset: over 4 rad/s between samples 4 and 5 after it
        ("runaway", lambda k: np.array(CENTRE) + [0.5e3 * (max(k - ONSET, 0) * DT) ** 2, 0], VELOCITY, ONSET + 5),
        # joint 2's encoder line breaks: INT32_MAX counts from the onset
        ("jump", lambda k: np.array(CENTRE) + [0, 0 if k < ONSET else 2**31 * STEP], JUMP, ONSET),
        # joint 2 drifts at 0.5 rad/s from the onset: out of the start ± 1 rad after 2 s
        ("workspace", lambda k: np.array(CENTRE) + [0, 0.5 * max(k - ONSET, 0) * DT], WORKSPACE, ONSET + 2001),
    ],
)
def test_each_fault_stops_the_run_at_zero_torque_on_the_tick_the_rule_says(tmp_path, fault, script, code, first):
    dev = Scripted(script)
    r = run_loop(dev, _tick(), 4.0, tmp_path / f"{fault}.csv", watchdog=1.0)
    assert r.stopped_by == "limit" and r.ticks == first + 1, (r.stopped_by, r.reason, r.ticks)
    assert fault.replace("runaway", "velocity") in r.reason and "zero torque sent" in r.reason
    acks = [a for a, _ in dev.commands]
    assert acks[-1] == first and np.all(dev.commands[-1][1] == 0)  # the trip's own sample answered with zero
    assert all(np.any(v != 0) for _, v in dev.commands[ONSET - 10 : ONSET])  # the controller was working
    if fault == "jump":  # `read` leaves the row of an encoder jump out, and says so
        with pytest.warns(RecordingNote, match="its encoder jumped"):
            rec = read(tmp_path / f"{fault}.csv")
        assert len(rec) == first and np.all(rec.extra["trip"] == 0)
    else:
        rec = read(tmp_path / f"{fault}.csv")
        assert len(rec) == first + 1 and rec.extra["trip"][-1] == code and np.all(rec.extra["trip"][:-1] == 0)
        assert np.all(rec.tau[-1] == 0)
    assert rec.meta["stopped_by"] == "limit" and rec.meta["reason"] == r.reason


def test_a_stall_at_the_torque_limit_stops_after_its_time(tmp_path):
    dev = Scripted(lambda k: np.array(CENTRE))  # the arm does not move, whatever is commanded
    r = run_loop(dev, _tick(Push()), 4.0, tmp_path / "stall.csv", watchdog=1.0)
    # commanded at the limit from sample 0 (it acts from then on): held 0.5 s at sample 500
    assert r.stopped_by == "limit" and "stall: joint 1" in r.reason and r.ticks == 501, r.reason
    rec = read(tmp_path / "stall.csv")
    assert np.all(rec.extra["clamped"][:-1] == 1) and np.all(np.abs(rec.tau[:-1, 0]) == Limits().torque)
    assert rec.extra["trip"][-1] == STALL and np.all(rec.tau[-1] == 0)


def test_the_loop_trips_on_its_own_when_the_stepper_does_not_check(tmp_path):
    """A stepper without limits of its own (the numpy baseline of `manus bench hardware`): the
    loop's check alone stops the runaway, on the same tick."""
    from manus.runs.bench.hardware import NumpyImpedance

    dev = Scripted(lambda k: np.array(CENTRE) + [0.5e3 * (max(k - ONSET, 0) * DT) ** 2, 0])
    r = run_loop(dev, NumpyImpedance(DT, CPR, INFO.torque_limit), 4.0, None, watchdog=1.0)
    assert r.stopped_by == "limit" and "velocity limit: joint 1" in r.reason and r.ticks == ONSET + 6


def test_a_smaller_rig_torque_limit_is_the_one_commanded(tmp_path):
    dev = Scripted(lambda k: np.array(CENTRE))
    tick = _tick(Push(), dataclasses.replace(Limits(), torque=1.5, stall_seconds=0.05))
    r = run_loop(dev, tick, 1.0, None, watchdog=1.0)
    assert r.stopped_by == "limit" and "stall" in r.reason
    assert max(abs(v[0]) for _, v in dev.commands) == pytest.approx(1.5, abs=2e-3)  # (through the volts)


@pytest.mark.parametrize(
    "what, age, skip",
    [
        ("late", lambda k: 3e-3 if k >= ONSET else 0.0, lambda k: 0),  # every sample 3 ms old from the onset
        ("lost", lambda k: 0.0, lambda k: int(k >= ONSET and k % 3 == 0)),  # one sample in three lost
    ],
)
def test_a_loop_that_cannot_keep_up_stops(tmp_path, what, age, skip):
    """Over 30 % of the last 200 ticks' commands late, or of their samples lost: the loop stops
    at zero torque (`limit`, "loop quality"), within the window's share of the onset."""
    dev = Scripted(lambda k: np.array(CENTRE), age, skip)
    limits = dataclasses.replace(Limits(), missed=0.3, lost=0.3, window=0.2)
    r = run_loop(dev, _tick(limits=limits), 4.0, tmp_path / f"{what}.csv", watchdog=1.0)
    assert r.stopped_by == "limit" and r.reason.startswith("loop quality"), r.reason
    last = dev.commands[-1][0]
    # late: the 61st late command of the window trips it; lost: the 61st lost sample (one per 2 ticks kept)
    assert ONSET < last <= ONSET + (61 if what == "late" else 3 * 61), (last, r.reason)
    rec = read(tmp_path / f"{what}.csv")
    assert rec.extra["trip"][-1] == LOOP and rec.meta["reason"] == r.reason
