"""The calibration set on 6–7-joint serial chains: the Panda (7 joints) and the UR5 (6 joints) of
example-robot-data, each recording simulated by one of two engines on the chain's URDF and then
written to a CSV file and read back (`manus.plants.recording.read`, the path a user's file takes:
header, transmission, time base).

Each recording's *condition* is drawn from its seed:

- robot: `panda` or `ur5` (armatures 0.1–0.3 kg m², viscous and dry friction per joint), or, where
  asked (`robots`, `--robots`), `xarm7`: its URDF states a 100:1 gear on every joint, so friction
  and the other motor-side effects act on its motors (levels of `FRICTION` felt at the joints,
  Fc / 100 and b / 100² on the motors; widths and Stribeck velocities 100 times the joints';
  `gear`). Its recordings keep the URDF's transmission, as a user's file read with that URDF does;
- rate: 100, 200, 500 or 1000 Hz (`RATES`; the physics stepped at 1 kHz or faster), `SECONDS` long;
- loop: `closed` (a computed-torque feedforward along a Fourier excitation plus a PD on the
  quantized encoder, `serial_sim.Feedforward`) or `open` (the torque of that loop run on exact
  positions, replayed: the recorded command does not answer the recorded encoder's noise);
- torque: `exact` (the command) or `white` (white noise of 10–30 % of each joint's torque RMS on
  the recorded torque, as a torque read from motor currents);
- friction: the dry friction law of the truth, `coulomb` (Fc sgn q̇) or `smooth` (Fs tanh(q̇/w),
  w drawn in `WIDTH`); the start model states it (`rigid,viscous,coulomb` or
  `rigid,viscous,smooth:W`);
- transmission: `none` or, on the UR5, `differential`: a differential wrist, its motors turning
  with θ5 = q5 + q6 and θ6 = q5 − q6 (`DIFFERENTIAL`), stated by the recording's `# transmission:`
  line, so the truth's friction acts on the motors and the start model reads it from the file.
  The simulator's set-valued friction step acts on the joints, so a differential wrist's truth
  has smooth friction (drawn `coulomb`, it is made `smooth`);
- engine: `manus` (`manus.plants.simulator.Simulator`: Störmer–Verlet sub-steps, set-valued
  friction; its equations of motion checked against pinocchio's in tests/plants/test_serial_sim.py)
  or, where the truth's friction is smooth, `pinocchio` (`_run_pinocchio`: pinocchio's
  articulated-body algorithm integrated by RK4, the friction and the hidden effect written here in
  numpy from their equations, the loop's PD in numpy: nothing of manus's simulator, effects or
  controller in the plant);
- log: `clean` or `repeated, jittered` (a PC's log: 2–5 % of the rows repeat the row before while
  the joints move, and the stamps scatter by ±10–30 % of the period, `manus.experiments.logs`),
  repaired by `read` where the positions show the true grid.

The later keys (friction, transmission, log, engine) are drawn from their own stream, so the robot, rate,
loop and torque of a seed are the same whatever they add.

The truth is the start model plus, in a hidden-effect case, one effect of `HIDDEN`:

- a per-joint effect (Stribeck, asymmetry, offset, cogging) on ONE joint (one of joints 1–4 under
  a differential wrist), sized at `AMPLITUDE` of that joint's torque RMS along the motion
  (`sizing.scale_hidden`): an effect a pooled 0.5 %-of-all-the-torque floor cannot see on a
  seven-joint chain, whose shoulder carries tens of N·m and whose wrist a few. A Stribeck hump
  refines Coulomb friction on joints: its recordings have `coulomb` friction and no transmission;
- `coupling`: friction (bc, Fcc) on q̇_I ± q̇_(I+1), two neighbouring joints (of joints 1–4 under a
  differential wrist), sized at `AMPLITUDE` of the two joints' torque RMS; named only with its
  joints and sign (the condition's `hidden_spec`);
- `smooth`: the truth's friction is smooth (every joint, its Coulomb level, width drawn in
  `WIDTH`) while the start model holds Coulomb's sign; its size is what the sign and the tanh
  differ by (`hidden_fraction`, per joint).

`case(seed, hidden)` returns a `manus.experiments.calibration.Case`; `manus bench diagnose
--calibrate --simulator chain` runs the set (judged by `manus.experiments.judging`, each
recording diagnosed with relevance per joint and, beside it, over all the torque only).
"""

from __future__ import annotations

import importlib
import importlib.metadata
import math
import tempfile
import time
import warnings
from dataclasses import dataclass, replace
from functools import cache
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from manus.adaptive.controllers import Replay
from manus.experiments import logs
from manus.experiments.calibration import Case, check_amplitude, check_rates
from manus.experiments.sizing import achieved, effect_torque, rms, scale_hidden
from manus.plants.closed_loop import simulate
from manus.plants.effects import Cogging, Coulomb, Coupling, Model, Rigid, Smooth, Stribeck, Viscous, parse_effect
from manus.plants.errors import ModelError, RecordingNote
from manus.plants.recording import from_trajectory, read, write
from manus.plants.references import Hold
from manus.plants.serial import Serial
from manus.plants.serial_sim import Feedforward, Fourier
from manus.plants.simulator import Encoder, Simulator
from manus.plants.transmission import parse, with_transmission

ROBOTS = {
    "panda": ("panda_description/urdf/panda.urdf", (0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8)),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", (0.0, -1.2, 1.2, -1.5, -1.5, 0.0)),
    "xarm7": ("xarm_description/urdf/xarm7.urdf", (0.0, 0.3, 0.0, 1.2, 0.0, 0.9, 0.0)),  # 100:1 gears in its URDF
}
DRAWN = ("panda", "ur5")  # the robots a seed draws from unless told (`--robots`)
FRICTION = {  # (dry friction level [N·m], viscous [N·m·s/rad]) per joint, as felt at the joint
    "panda": ((0.5, 0.5, 0.4, 0.4, 0.3, 0.3, 0.2), (0.3, 0.3, 0.25, 0.25, 0.15, 0.15, 0.1)),
    "ur5": ((1.0, 1.0, 0.8, 0.3, 0.3, 0.3), (0.6, 0.6, 0.5, 0.15, 0.15, 0.15)),
    "xarm7": ((1.0, 1.0, 0.8, 0.8, 0.4, 0.4, 0.2), (0.5, 0.5, 0.4, 0.4, 0.2, 0.2, 0.1)),
}
RATES = (100, 200, 500, 1000)
LOOPS = ("closed", "open")
TORQUES = ("exact", "white")
FRICTIONS = ("coulomb", "smooth")
TRANSMISSIONS = ("none", "differential")
LOGS = ("clean", "repeated, jittered")
ENGINES = ("manus", "pinocchio")
WHITE = (0.10, 0.30)
WIDTH = (0.05, 0.2)  # the smooth friction's width [rad/s] (a 7-joint arm's: a sigmoid over ±0.1–0.2 rad/s)
REPEATED = (0.02, 0.05)  # a corrupted log's share of repeated rows ...
JITTER = (0.1, 0.3)  # ... and its stamps' scatter, ± this share of the period (uniform)
DIFFERENTIAL = "m5 = q5 + q6; m6 = q5 - q6"  # the UR5's differential wrist
HIDDEN = ("stribeck", "asymmetry", "offset", "cogging", "smooth", "coupling")
START = "rigid,viscous,coulomb"
AMPLITUDE = 0.03  # a hidden effect's torque RMS as a fraction of its joint's (a coupling: of its two joints')
SECONDS = 8.0
PHYSICS_HZ = 1000  # the physics is stepped at least this often
COUNTS = 2**17  # encoder counts per revolution
SWING = 0.5  # the Fourier excitation's amplitude per joint [rad]
STRIBECK_VS = 0.05  # [rad/s]
FREE = 4  # under a differential wrist, per-joint effects and couplings are hidden on joints 1..FREE


@dataclass(frozen=True)
class Chain:
    """What `manus.experiments.sizing` needs of a structure (a `setup`)."""

    name: str
    structure: Serial
    centre: tuple
    prismatic: bool = False

    @property
    def n(self) -> int:
        return self.structure.n_joints


@cache
def chain(name: str) -> Chain:
    """The robot `name` of `ROBOTS` from example-robot-data, armatures 0.1–0.3 kg m²."""
    relative, centre = ROBOTS[name]
    try:
        share = importlib.metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share")
    except importlib.metadata.PackageNotFoundError:
        raise ModelError("the chain calibration needs example-robot-data (pip install example-robot-data)") from None
    path = str(share / "example-robot-data" / "robots" / relative)
    n = Serial.from_urdf(path).n_joints
    return Chain(name, Serial.from_urdf(path, armature=np.linspace(0.1, 0.3, n)), centre)


def draw_condition(
    seed: int, rates: tuple = RATES, hidden: str | None = None, robots: tuple = DRAWN, **overrides
) -> dict:
    """The condition of case `seed` with `hidden` hidden, its robot drawn from `robots` (overrides
    win; a Stribeck hump has Coulomb friction on joints, a differential wrist and the pinocchio
    engine smooth friction)."""
    unknown_robots = [r for r in robots if r not in ROBOTS]
    if not robots or unknown_robots:
        raise ValueError(f"robots: {', '.join(ROBOTS)} (got {', '.join(robots) or 'none'})")
    rng = np.random.default_rng([seed, 29])
    c = {
        "structure": str(rng.choice(tuple(robots))),
        "rate": int(rng.choice(check_rates(rates))),
        "excitation": str(rng.choice(LOOPS)),
        "torque": str(rng.choice(TORQUES)),
        "hold": "stated",
    }
    more = np.random.default_rng([seed, 37])
    c["friction"] = str(more.choice(FRICTIONS))
    c["transmission"] = str(more.choice(TRANSMISSIONS))
    c["log"] = str(more.choice(LOGS))
    c["engine"] = str(more.choice(ENGINES))
    unknown = set(overrides) - set(c)
    if unknown:
        raise ValueError(f"unknown condition key(s) {sorted(unknown)}: {', '.join(c)}")
    given = dict(overrides)
    c.update(overrides)
    if c["structure"] != "ur5" and "transmission" not in given:
        c["transmission"] = "none"
    if hidden == "stribeck":
        c.update({k: v for k, v in (("friction", "coulomb"), ("transmission", "none")) if k not in given})
    elif hidden == "smooth":
        c["friction"] = "smooth"  # (the truth's; the start holds Coulomb's sign)
    elif c["transmission"] == "differential" and "friction" not in given:
        c["friction"] = "smooth"
    if c["engine"] == "pinocchio" and "engine" not in given and c["friction"] != "smooth":
        c["engine"] = "manus"
    if c["engine"] == "pinocchio" and c["friction"] != "smooth":
        raise ValueError("the pinocchio engine's truth has smooth friction (RK4: no set-valued friction)")
    if c["transmission"] == "differential" and c["structure"] != "ur5":
        raise ValueError("a differential wrist is the UR5's (structure ur5)")
    if c["transmission"] == "differential" and c["friction"] == "coulomb":
        raise ValueError(
            "a differential wrist's truth has smooth friction (the simulator steps dry friction on joints)"
        )
    if hidden == "stribeck" and (c["friction"] != "coulomb" or c["transmission"] != "none"):
        raise ValueError(
            "a hidden Stribeck hump refines Coulomb friction on joints: friction coulomb, transmission none"
        )
    return c


def _run(ch: Chain, model: Model, params: dict, rate: int, loop: str, seconds: float, seed: int):
    """One simulated run (the trajectory) of `model` with `params`; open loop: the closed loop's
    torque on exact positions, replayed."""
    sub = max(1, math.ceil(PHYSICS_HZ / rate))
    centre = np.asarray(ch.centre, float)
    reference = Fourier(centre, amplitude=SWING, f0=0.2, harmonics=5, decay=1.5, seed=seed % 2**31)
    key = jax.random.PRNGKey(seed % 2**31)

    def sim(encoder):
        return Simulator(model, params, rate_hz=rate, substeps=sub, actuator=None, encoder=encoder, q0=centre)

    quantized = Encoder.counts_per_rev(COUNTS)
    controller = Feedforward(ch.structure, 1.0 / rate)
    if loop == "closed":
        return simulate(sim(quantized), controller, reference, seconds, key=key)
    exact = simulate(sim(Encoder(step=1e-12)), controller, reference, seconds, key=key)
    return simulate(sim(quantized), Replay(jnp.asarray(exact.tau)), Hold(centre), seconds, key=key)


def _pinocchio_model(ch: Chain):
    """The chain's URDF in pinocchio (the joints off the chain locked at zero), its armatures."""
    try:
        pin: Any = importlib.import_module("pinocchio")  # (a compiled module without stubs)
    except ImportError:
        raise ModelError("the chain calibration's pinocchio engine needs pinocchio (pip install pin)") from None
    serial = ch.structure
    model = pin.buildModelFromUrdf(serial.urdf_file)
    locked = [model.getJointId(name) for name in model.names[1:] if name not in serial.joint_names]
    if locked:
        model = pin.buildReducedModel(model, locked, np.zeros(model.nq))
    model.armature = np.asarray(serial.defaults, float)[10 * ch.n :]
    return pin, model


def _friction_np(ch: Chain, params: dict, width: float, effect, N: np.ndarray):
    """The truth's friction and hidden effect in numpy, from the equations (not manus's effects):
    on the motors θ = N q, b θ̇ + Fs tanh(θ̇/w) and a per-motor hidden effect, mapped by Nᵀ; a
    coupling c (bc v + Fcc sgn v), v = c·q̇, on the joints."""
    n = ch.n
    b = np.array([params[f"b{i + 1}"] for i in range(n)])
    fs = np.array([params[f"Fs{i + 1}"] for i in range(n)])
    extra = None
    if effect is not None:
        v = np.array([params[k] for k in effect.names(ch.structure)])
        if isinstance(effect, Coupling):
            c = np.zeros(n)
            c[int(effect.first)], c[int(effect.second)] = 1.0, float(effect.sign)
            extra = lambda q, qd: c * (v[0] * (c @ qd) + v[1] * np.sign(c @ qd))
        elif effect.name == "offset":
            extra = lambda q, qd: N.T @ v
        elif effect.name == "asymmetry":
            extra = lambda q, qd: N.T @ (v * np.abs(N @ qd))
        elif isinstance(effect, Cogging):
            order = float(effect.orders[0])
            extra = lambda q, qd: N.T @ (v[:n] * np.sin(order * (N @ q)) + v[n:] * np.cos(order * (N @ q)))
        else:
            raise ValueError(f"the pinocchio engine has no equations for {effect.name}")

    def torque(q, qd):
        th = N @ qd
        out = N.T @ (b * th + fs * np.tanh(th / width))
        return out if extra is None else out + extra(q, qd)

    return torque


def _run_pinocchio(ch: Chain, params: dict, width: float, effect, rate: int, loop: str, seconds: float, seed: int):
    """One closed-loop run on pinocchio's articulated-body algorithm (forward dynamics, armatures
    included) with classical RK4 sub-steps of at most 1 ms, the friction and hidden effect written
    here (`_friction_np`): the same loop as `_run`'s (`Feedforward`'s computed torque on pinocchio's
    inverse dynamics along the Fourier excitation, a PD on the quantized encoder with a 100 Hz
    filtered difference), each command held over its period; open loop: the PD on the exact
    positions (the command replayed, as `_run` does, is that run's own)."""
    from types import SimpleNamespace

    pin, model = _pinocchio_model(ch)
    data = model.createData()
    n, dt = ch.n, 1.0 / rate
    sub = max(1, math.ceil(PHYSICS_HZ / rate))
    h = dt / sub
    N = np.eye(n) if ch.structure.transmission is None else ch.structure.transmission.matrix
    friction = _friction_np(ch, params, width, effect, N)
    centre = np.asarray(ch.centre, float)
    reference = Fourier(centre, amplitude=SWING, f0=0.2, harmonics=5, decay=1.5, seed=seed % 2**31)
    steps = int(round(seconds * rate))
    t = np.arange(steps) * dt
    ref = jax.vmap(reference)(jnp.asarray(t))
    rq, rqd, rqdd = (np.asarray(x) for x in ref)
    ff = np.stack([pin.rnea(model, data, a, b, c) + model.armature * c for a, b, c in zip(rq, rqd, rqdd, strict=True)])
    step = 2 * np.pi / COUNTS
    smooth = 1.0 - math.exp(-2 * math.pi * 100.0 * dt)
    k_p, k_d = 400.0, 20.0

    def f(q, qd, tau):
        return qd, pin.aba(model, data, q, qd, tau - friction(q, qd))

    q, qd = centre.copy(), np.zeros(n)
    before, speed = (np.round(q / step) * step if loop == "closed" else q.copy()), np.zeros(n)
    out = np.zeros((5, steps, n))  # measured q, command, true q, true q̇, reference
    for k in range(steps):
        measured = np.round(q / step) * step
        seen = measured if loop == "closed" else q
        speed = speed + smooth * ((seen - before) / dt - speed)
        before = seen
        tau = ff[k] + k_p * (rq[k] - seen) + k_d * (rqd[k] - speed)
        out[:, k] = measured, tau, q, qd, rq[k]
        for _ in range(sub):
            a1, b1 = f(q, qd, tau)
            a2, b2 = f(q + h / 2 * a1, qd + h / 2 * b1, tau)
            a3, b3 = f(q + h / 2 * a2, qd + h / 2 * b2, tau)
            a4, b4 = f(q + h * a3, qd + h * b3, tau)
            q = q + h / 6 * (a1 + 2 * a2 + 2 * a3 + a4)
            qd = qd + h / 6 * (b1 + 2 * b2 + 2 * b3 + b4)
    measured, tau, q_true, qd_true, q_ref = out
    return SimpleNamespace(t=t, q=measured, tau=tau, q_true=q_true, qd_true=qd_true, q_ref=q_ref)


def _coupling(rng: np.random.Generator, n: int) -> Coupling:
    """A coupling of two neighbouring joints of the first `n`, either sign, as diagnose's search
    writes it (`Coupling.space`: q̇_(I+1) − q̇_I or q̇_I + q̇_(I+1))."""
    i = int(rng.integers(n - 1))
    return (
        Coupling(first=i + 1, second=i, sign=-1.0) if rng.random() < 0.5 else Coupling(first=i, second=i + 1, sign=1.0)
    )


def same_coupling(a: str, b: str) -> bool:
    """Whether the specs `a` and `b` (an effect's or a model's) hold one coupling: the same two
    joints and sign (c or −c)."""

    def of(spec: str) -> Coupling | None:
        part = next((x for x in spec.split(",") if x.strip().startswith("coupling")), None)
        e = None if part is None else parse_effect(part)
        return e if isinstance(e, Coupling) else None

    x, y = of(a), of(b)
    return x is not None and y is not None and set(x.joints) == set(y.joints) and float(x.sign) == float(y.sign)


def gear(ch: Chain) -> float:
    """The robot's own reduction, the same on every joint (its URDF's `<transmission>` elements; 1:
    none): what turns `FRICTION`'s levels, felt at the joints, into its motors' (Fc / r, b / r²)
    and a width or a Stribeck velocity into the motor's speeds (× r)."""
    N = ch.structure.transmission
    if N is None:
        return 1.0
    r = np.diag(N.matrix)
    if not (np.allclose(N.matrix, np.diag(r)) and np.allclose(r, r[0]) and r[0] > 0):
        raise ValueError(f"{ch.name}: its own transmission is not one common gear")
    return float(r[0])


def case(
    seed: int,
    hidden: str | None = None,
    rates: tuple = RATES,
    amplitude: float = AMPLITUDE,
    robots: tuple = DRAWN,
    **overrides,
) -> Case:
    """Chain recording `seed`: nothing hidden, or one effect of `HIDDEN` (a per-joint one on one
    joint at `amplitude` of that joint's torque RMS), the robot drawn from `robots`. Keyword
    overrides fix condition values (structure: the robot, rate, excitation: the loop, torque,
    friction, transmission, log)."""
    check_amplitude(amplitude)
    if hidden is not None and hidden not in HIDDEN:
        raise ValueError(f"the chain set hides one of {', '.join(HIDDEN)} (got {hidden!r})")
    t0 = time.perf_counter()
    c = draw_condition(seed, rates, hidden, robots, **overrides)
    plain = chain(c["structure"])
    wrist = c["transmission"] == "differential"
    structure = with_transmission(plain.structure, parse(DIFFERENTIAL, plain.n)) if wrist else plain.structure
    ch = replace(plain, structure=structure)
    r = gear(plain)
    rate, dt = c["rate"], 1.0 / c["rate"]
    rng = np.random.default_rng([seed, 31])
    more = np.random.default_rng([seed, 41])
    fc, b = (tuple(f / r for f in FRICTION[ch.name][0]), tuple(x / r**2 for x in FRICTION[ch.name][1]))
    width = round(float(more.uniform(*WIDTH)) * r, 3)
    law = Smooth(width=width) if c["friction"] == "smooth" else Coulomb()
    level = "Fs" if c["friction"] == "smooth" else "Fc"
    params = {**{f"{level}{i + 1}": v for i, v in enumerate(fc)}, **{f"b{i + 1}": v for i, v in enumerate(b)}}
    start = START if hidden == "smooth" or c["friction"] == "coulomb" else f"rigid,viscous,{law.spec}"
    order = float(rng.integers(20, 61))
    free = FREE if wrist else ch.n
    effect = None
    if hidden == "coupling":
        effect = _coupling(more, free)
    elif hidden == "stribeck":
        effect = Stribeck(vs=STRIBECK_VS * r)
    elif hidden == "cogging":
        effect = Cogging(order=order)
    elif hidden not in (None, "smooth"):
        effect = parse_effect(hidden)
    truth = Model(structure, (Rigid(), Viscous(), law) + (() if effect is None else (effect,)))
    full = {**truth.defaults(), **params}

    def run(values: dict):
        if c["engine"] == "pinocchio":
            return _run_pinocchio(ch, values, width, effect, rate, c["excitation"], SECONDS, seed)
        return _run(ch, truth, values, rate, c["excitation"], SECONDS, seed)

    info: dict = {"width": width} if c["friction"] == "smooth" else {}
    joint = None
    if effect is not None:
        unit = {k: float(v) for k, v in zip(effect.names(structure), effect.defaults(structure), strict=True)}
        null = {**full, **{k: 0.0 for k in unit}}
        first = run(null)
        if isinstance(effect, Coupling):
            on = [j - 1 for j in effect.joints]
            tau_e = effect_torque(plain, effect, unit, first.q_true, first.qd_true, np.zeros_like(first.qd_true))
            ratio = rms(tau_e[:, on].ravel()) / rms(np.asarray(first.tau)[:, on].ravel())
            hp = {k: v * amplitude / ratio for k, v in unit.items()}
            info["hidden_spec"] = effect.spec
        else:
            joint = int(rng.integers(free)) + 1
            hp, _ = scale_hidden(plain, effect, unit, joint, first, amplitude, dt)
        full = {**full, **hp}
        traj = run(full)
        info["hidden_fraction"] = [round(x, 4) for x in achieved(plain, effect, hp, traj, dt, joint)]
        if hidden == "cogging":
            info["order"] = order
    else:
        traj = run(full)
        if hidden == "smooth":  # what Coulomb's sign and the tanh differ by, per joint
            levels = dict(enumerate(fc, 1))
            sign = Model(structure, (Coulomb(),)).torque
            tanh = Model(structure, (law,)).torque
            gap = jax.vmap(
                lambda q, v: (
                    sign(q, v, 0 * v, {f"Fc{i}": f for i, f in levels.items()})
                    - tanh(q, v, 0 * v, {f"Fs{i}": f for i, f in levels.items()})
                )
            )(jnp.asarray(traj.q_true), jnp.asarray(traj.qd_true))
            info["hidden_fraction"] = [round(float(x), 4) for x in rms(np.asarray(gap)) / rms(np.asarray(traj.tau))]
    meta = {"calibration": f"chain seed {seed}"} | ({"transmission": DIFFERENTIAL} if wrist else {})
    rec = from_trajectory(traj, rate, plain.structure, COUNTS, meta)
    rec.qd = None
    rec.extra = {}
    if c["torque"] == "white":
        noise = float(rng.uniform(*WHITE))
        rec.tau = rec.tau + rng.standard_normal(rec.tau.shape) * (noise * rms(rec.tau))
        info["noise_fraction"] = round(noise, 3)
    if c["log"] != "clean":
        share, scatter = float(more.uniform(*REPEATED)), float(more.uniform(*JITTER))
        rec = logs.jitter_stamps(logs.repeat_rows(rec, share, more)[0], scatter, more)
        info.update(repeated=round(share, 4), jitter=round(scatter, 3))
    rec = _through_a_file(rec, plain.structure)
    if rec.time_base is not None:
        info["time_base"] = rec.time_base.note
    rec.path = f"<chain calibration seed {seed}, hidden {hidden or 'nothing'}>"
    cond = {"seed": seed, **c, **info}
    rigid = set(structure.rigid_names)
    values = {k: float(v) for k, v in full.items() if k not in rigid and float(v) != 0.0}
    return Case(rec, start, hidden, joint, cond, values, time.perf_counter() - t0)


def _through_a_file(rec, serial: Serial):
    """`rec` written to a CSV file and read back as a user's file is (`read`: its header, its
    transmission, its time base repaired), on the simulated chain (the URDF states no armatures)."""
    with tempfile.TemporaryDirectory(prefix="manus-chain-") as folder:
        path = write(rec, Path(folder) / "chain.csv")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RecordingNote)  # (the time base's note is kept on the recording)
            out = read(path)
    out.serial = serial
    return out
