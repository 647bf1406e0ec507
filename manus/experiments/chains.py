"""The calibration set on 6–7-joint serial chains: the Panda (7 joints) and the UR5 (6 joints) of
example-robot-data, simulated by `manus.plants.simulator.Simulator` on the chain's URDF (its
equations of motion checked against pinocchio's in tests/plants/test_serial_sim.py).

Each recording's *condition* is drawn from its seed:

- robot: `panda` or `ur5` (armatures 0.1–0.3 kg m², viscous and Coulomb friction per joint);
- rate: 100, 200, 500 or 1000 Hz (`RATES`; the physics stepped at 1 kHz or faster), `SECONDS` long;
- loop: `closed` (a computed-torque feedforward along a Fourier excitation plus a PD on the
  quantized encoder, `serial_sim.Feedforward`) or `open` (the torque of that loop run on exact
  positions, replayed: the recorded command does not answer the recorded encoder's noise);
- torque: `exact` (the command) or `white` (white noise of 10–30 % of each joint's torque RMS on
  the recorded torque, as a torque read from motor currents).

The truth is `rigid,viscous,coulomb` (the start model) plus, in a hidden-effect case, one
per-joint effect on ONE joint (`HIDDEN`), sized at `AMPLITUDE` of that joint's torque RMS along the
motion (`sizing.scale_hidden`): an effect a pooled 0.5 %-of-all-the-torque floor cannot see on a
seven-joint chain, whose shoulder carries tens of N·m and whose wrist a few.

`case(seed, hidden)` returns a `manus.experiments.calibration.Case`; `manus bench diagnose
--calibrate --simulator chain` runs the set (judged by `manus.experiments.judging`, each
recording diagnosed with relevance per joint and, beside it, over all the torque only).
"""

from __future__ import annotations

import importlib.metadata
import math
import time
from dataclasses import dataclass
from functools import cache

import jax
import jax.numpy as jnp
import numpy as np

from manus.adaptive.controllers import Replay
from manus.experiments.calibration import Case, check_amplitude, check_rates
from manus.experiments.sizing import achieved, scale_hidden
from manus.plants.closed_loop import simulate
from manus.plants.effects import Cogging, Model, Stribeck
from manus.plants.errors import ModelError
from manus.plants.recording import from_trajectory
from manus.plants.references import Hold
from manus.plants.serial import Serial
from manus.plants.serial_sim import Feedforward, Fourier
from manus.plants.simulator import Encoder, Simulator

ROBOTS = {
    "panda": ("panda_description/urdf/panda.urdf", (0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8)),
    "ur5": ("ur_description/urdf/ur5_robot.urdf", (0.0, -1.2, 1.2, -1.5, -1.5, 0.0)),
}
FRICTION = {  # (Coulomb [N·m], viscous [N·m·s/rad]) per joint
    "panda": ((0.5, 0.5, 0.4, 0.4, 0.3, 0.3, 0.2), (0.3, 0.3, 0.25, 0.25, 0.15, 0.15, 0.1)),
    "ur5": ((1.0, 1.0, 0.8, 0.3, 0.3, 0.3), (0.6, 0.6, 0.5, 0.15, 0.15, 0.15)),
}
RATES = (100, 200, 500, 1000)
LOOPS = ("closed", "open")
TORQUES = ("exact", "white")
WHITE = (0.10, 0.30)
HIDDEN = ("stribeck", "asymmetry", "offset", "cogging")
START = "rigid,viscous,coulomb"
AMPLITUDE = 0.03  # a hidden effect's torque RMS as a fraction of its joint's
SECONDS = 8.0
PHYSICS_HZ = 1000  # the physics is stepped at least this often
COUNTS = 2**17  # encoder counts per revolution
SWING = 0.5  # the Fourier excitation's amplitude per joint [rad]
STRIBECK_VS = 0.05  # [rad/s]


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


def draw_condition(seed: int, rates: tuple = RATES, **overrides) -> dict:
    """The condition of case `seed` (overrides win)."""
    rng = np.random.default_rng([seed, 29])
    c = {
        "structure": str(rng.choice(tuple(ROBOTS))),
        "rate": int(rng.choice(check_rates(rates))),
        "excitation": str(rng.choice(LOOPS)),
        "torque": str(rng.choice(TORQUES)),
        "hold": "stated",
    }
    unknown = set(overrides) - set(c)
    if unknown:
        raise ValueError(f"unknown condition key(s) {sorted(unknown)}: {', '.join(c)}")
    c.update(overrides)
    return c


def _truth(ch: Chain, hidden: str | None, order: float) -> Model:
    spec = START if hidden is None else f"{START},{hidden}"
    m = Model(ch.structure, spec)
    return m.with_effect(Cogging(order=order)) if hidden == "cogging" else m


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


def case(seed: int, hidden: str | None = None, rates: tuple = RATES, amplitude: float = AMPLITUDE, **overrides) -> Case:
    """Chain recording `seed`: nothing hidden, or one effect of `HIDDEN` on one joint at
    `amplitude` of that joint's torque (RMS). Keyword overrides fix condition values
    (structure: the robot, rate, excitation: the loop, torque)."""
    check_amplitude(amplitude)
    if hidden is not None and hidden not in HIDDEN:
        raise ValueError(f"the chain set hides one of {', '.join(HIDDEN)} (got {hidden!r})")
    t0 = time.perf_counter()
    c = draw_condition(seed, rates, **overrides)
    ch = chain(c["structure"])
    rate, dt = c["rate"], 1.0 / c["rate"]
    rng = np.random.default_rng([seed, 31])
    fc, b = FRICTION[ch.name]
    params = {**{f"Fc{i + 1}": v for i, v in enumerate(fc)}, **{f"b{i + 1}": v for i, v in enumerate(b)}}
    order = float(rng.integers(20, 61))
    truth = _truth(ch, hidden, order)
    full = {**truth.defaults(), **params}
    info: dict = {}
    joint = None
    if hidden is not None:
        joint = int(rng.integers(ch.n)) + 1
        effect = truth.get(hidden)
        assert effect is not None
        if hidden == "stribeck":
            effect = Stribeck(vs=STRIBECK_VS)
            truth = truth.with_effect(effect)
        unit = {k: float(v) for k, v in zip(effect.names(ch.structure), effect.defaults(ch.structure), strict=True)}
        null = {**full, **{k: 0.0 for k in unit}}
        first = _run(ch, truth, null, rate, c["excitation"], SECONDS, seed)
        hp, _ = scale_hidden(ch, effect, unit, joint, first, amplitude, dt)
        full = {**full, **hp}
        traj = _run(ch, truth, full, rate, c["excitation"], SECONDS, seed)
        info["hidden_fraction"] = [round(x, 4) for x in achieved(ch, effect, hp, traj, dt, joint)]
        if hidden == "cogging":
            info["order"] = order
    else:
        traj = _run(ch, truth, full, rate, c["excitation"], SECONDS, seed)
    rec = from_trajectory(traj, rate, ch.structure, COUNTS, {"calibration": f"chain seed {seed}"})
    rec.qd = None
    rec.extra = {}
    if c["torque"] == "white":
        level = float(rng.uniform(*WHITE))
        rms = np.sqrt(np.mean(rec.tau**2, axis=0))
        rec.tau = rec.tau + rng.standard_normal(rec.tau.shape) * (level * rms)
        info["noise_fraction"] = round(level, 3)
    rec.path = f"<chain calibration seed {seed}, hidden {hidden or 'nothing'}>"
    cond = {"seed": seed, **c, **info}
    rigid = set(ch.structure.rigid_names)
    values = {k: float(v) for k, v in full.items() if k not in rigid and float(v) != 0.0}
    return Case(rec, START, hidden, joint, cond, values, time.perf_counter() - t0)
