"""The calibration set of `manus diagnose`: simulated recordings whose missing effect is known.

Every recording is made with the project's simulator, under one *condition* drawn from its seed:

- structure: the MANUS-2 arm (`arm`: 2 joints, radians, 131072 counts/rev) or a prismatic axis
  (`axis`: 1 joint in metres, a 1 µm encoder, a few kg, forces in N);
- rate: 1000 or 200 Hz (or drawn from the rates a user asks for: `--rates`; 12 s at 1 kHz and
  faster, 20 s below);
- excitation: `multisine` (closed loop, impedance control following a multi-sine), `reaching`
  (closed loop: smooth moves between random targets with rests in between) or `steps` (open
  loop: a replayed schedule of torque steps, zero-mean doublets in both directions with rests);
- torque: `exact` (the recorded torque is the command), `white` (white noise of 10–30 % of the
  torque's RMS added to the *recorded* torque: the plant got the exact command) or `coloured`
  (a low-passed random torque acting on the plant and absent from the recording);
- hold: `stated` (`command_hold: zoh` in the metadata) or `not stated` (the key removed).

The truth is the nominal model (`rigid,viscous,coulomb`; the thesis's values on the arm) plus, in
a hidden-effect case, one effect the analysis does not start from. A linear effect is built
generically from `Model(structure, effect).defaults()`: on the chosen joint (or on all) every
parameter is scaled by one factor so that the effect's torque along the recorded motion has an
RMS of `AMPLITUDE` (5 %) of the recorded torque's (simulate with it absent, measure, rescale,
simulate; once more if the result is off by more than `TOLERANCE`). A `delay` is sized the same
way by what the late command changes, τ(t) − τ(t − d) (`sizing.delay_change`), to `AMPLITUDE` of the torque
(RMS, all joints), but at least 1 ms (the thesis's amplifier; open-loop steps change more than that
with it) and at most `sizing.DELAY_MAX`; `compliance` is a lightly damped shaft mode at 15–30 % of the
sample rate (inside the band the recording resolves), drawn only under the open-loop steps,
which ring it. Hidden `rigid`, `viscous` or `coulomb` replace the nominal term (start without it);
a hidden effect that is an alternative to a nominal one (`Effect.replaces`: smooth friction, at the
setup's width, for Coulomb's sign) takes its place in the truth while the start keeps it.

How much of a hidden effect the data can tell from every other reading is measured beside it:
`sizing.distinct` (in the case's condition, `distinct_fraction`), the part of its torque left once the
start model plus any one other effect has explained what it can (a hidden delay: the RMS of what
it changes in the torque, `hidden_fraction`).

`case(seed, hidden)` returns a `Case`; `pendulum(seed)` an errors-in-variables case (a coarse
encoder at 200 Hz on a swinging pendulum) with its true parameters. `manus bench diagnose
--calibrate` runs the set; `tests/runs/test_calibration.py` a seeded subset of it.

Simulations are compiled once per (structure, rate, excitation, delay or compliance): the
parameters, references, schedules and disturbances are array leaves of the simulated pytree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np

from manus.adaptive.controllers import Replay
from manus.adaptive.impedance import Impedance
from manus.estimators.base import FilteredFirstDifference
from manus.experiments.sizing import (
    DELAY_MIN,
    achieved,
    applies,
    delay_change,
    distinct,
    parameter_joints,
    rms,
    scale_hidden,
    size_delay,
)
from manus.plants.closed_loop import simulate
from manus.plants.disturbed import Disturbed
from manus.plants.effects import ORDER, VOCABULARY, Cogging, Compliance, Delay, Model, Smooth, Stribeck
from manus.plants.recording import Recording, from_trajectory
from manus.plants.references import Hold, MultiSine, Reaching
from manus.plants.simulator import Actuator, Encoder, Simulator
from manus.plants.structures import Axis, Manus2, Structure

# -- the conditions ------------------------------------------------------------------------------
STRUCTURES = ("arm", "axis")
RATES = (1000, 200)
EXCITATIONS = ("multisine", "reaching", "steps")
TORQUES = ("exact", "white", "coloured")
HOLDS = ("stated", "not stated")
FAST = 1000  # Hz: a recording at this rate or faster lasts 12 s, a slower one 20 s
NOMINAL = ("rigid", "viscous", "coulomb")  # what the truth always holds (the thesis's model)
AMPLITUDE = 0.05  # a hidden effect's torque RMS, as a fraction of the recorded torque's (per joint)
TOLERANCE = 0.1  # re-scale once more when the achieved fraction is off by more than this (relative)
WHITE = (0.10, 0.30)  # white noise on the recorded torque: std as a fraction of its RMS
COLOURED = (
    0.03,
    0.08,
)  # the unrecorded disturbance: RMS as a fraction of the torque's RMS (the size of the hidden effect) ...
COLOURED_HZ = (1.0, 5.0)  # ... low-passed (2nd-order Butterworth) at a corner in this range [Hz]
COMPLIANCE_BAND = (0.15, 0.30)  # hidden shaft mode: f as a fraction of the sample rate
COMPLIANCE_ZETA = (0.005, 0.03)


@dataclass(frozen=True)
class Setup:
    """What a structure needs to be simulated and excited."""

    name: str
    structure: Structure
    nominal: dict  # the nominal effects' true values
    centre: tuple
    encoder_step: float  # [rad or m]
    actuator: Actuator
    stiffness: float  # impedance gains
    damping: float
    swing: float  # multi-sine amplitude and reaching range about the centre [rad or m]
    step_torque: tuple  # open-loop step amplitude per joint [N·m or N]
    step_seconds: tuple  # (shortest, longest) half-period of a step doublet [s]
    cogging_period: tuple  # range of the hidden cogging's period [rad or m]
    stribeck_vs: float  # the hidden Stribeck velocity [rad/s or m/s]
    prismatic: bool
    smooth_width: float = 0.1  # the hidden smooth friction's width [rad/s or m/s]

    @property
    def n(self) -> int:
        return self.structure.n_joints

    def meta(self) -> dict:
        if self.prismatic:
            return {"position_step": f"{self.encoder_step:g}", "joints": "prismatic"}
        return {}


ARM = Setup(
    "arm",
    Manus2(),
    Model(Manus2(), ",".join(NOMINAL)).defaults(),
    (0.464, 2.409),
    2 * math.pi / 131072,
    Actuator(),
    30.0,
    1.0,
    0.3,
    (1.2, 0.7),
    (0.08, 0.25),
    (2 * math.pi / 60, 2 * math.pi / 25),
    0.05,
    False,
)
AXIS = Setup(
    "axis",
    Axis(n_joints=1),
    {"M1": 2.5, "b1": 15.0, "Fc1": 5.0},
    (0.0,),
    1e-6,
    Actuator(dac_bits=16, torque_constant=25.0),
    1500.0,
    50.0,
    0.05,
    (25.0,),
    (0.03, 0.10),
    (0.005, 0.015),
    0.02,
    True,
    smooth_width=0.01,
)
SETUPS = {"arm": ARM, "axis": AXIS}


def hidden_effects() -> tuple[str, ...]:
    """Every effect of the vocabulary (read at run time: a new effect joins the set)."""
    return tuple(ORDER)


@dataclass
class Case:
    rec: Recording
    start: str  # the model the analysis starts from
    hidden: str | None
    joint: int | None  # 1-based joint where the effect was hidden; None: every joint
    condition: dict
    truth: dict = field(default_factory=dict)  # the true parameters (linear ones; the pendulum's)
    seconds: float = 0.0  # compute time of the simulation [s]

    def describe(self) -> str:
        c = self.condition
        where = "" if self.joint is None else f" on joint {self.joint}"
        return (
            f"seed {c.get('seed')}: {c.get('structure')} {c.get('rate')} Hz {c.get('excitation')}, torque "
            f"{c.get('torque')}, hold {c.get('hold')}; hidden {self.hidden or 'nothing'}{where}"
        )


# -- simulation building blocks ------------------------------------------------------------------
def reaching(setup: Setup, seconds: float, rng: np.random.Generator) -> Reaching:
    """Moves of 0.4–1.0 s to targets within ±swing of the centre, each followed by a rest of
    0.3–1.0 s; a fixed number of moves for a given length (one compilation)."""
    m = int(math.ceil(seconds / 0.7)) + 1
    centre = np.asarray(setup.centre, float)
    t, now, t0, dur, delta = 0.5, centre.copy(), [], [], []
    for _ in range(m):
        target = centre + rng.uniform(-setup.swing, setup.swing, setup.n)
        d = rng.uniform(0.4, 1.0)
        t0.append(t)
        dur.append(d)
        delta.append(target - now)
        now, t = target, t + d + rng.uniform(0.3, 1.0)
    return Reaching(jnp.asarray(centre), jnp.asarray(t0), jnp.asarray(dur), jnp.asarray(np.array(delta)))


def step_schedule(setup: Setup, steps: int, dt: float, rng: np.random.Generator) -> np.ndarray:
    """Open-loop torque steps per joint: doublets +A (T), −A (2T), +A (T) of random sign, level
    and length (zero impulse and zero mean: the motion returns near where it started), with rests
    of 0–0.3 s between them."""
    u = np.zeros((steps, setup.n))
    lo, hi = setup.step_seconds
    for j in range(setup.n):
        k = int(rng.integers(0, int(0.2 / dt) + 1))
        while k < steps:
            a = setup.step_torque[j] * rng.uniform(0.6, 1.0) * rng.choice([-1.0, 1.0])
            h = max(1, int(round(rng.uniform(lo, hi) / dt)))
            for level, length in ((a, h), (-a, 2 * h), (a, h)):
                u[k : k + length, j] = level
                k += length
            k += int(rng.integers(0, int(0.3 / dt) + 1))
    return u


def coloured(steps: int, dt: float, rms: np.ndarray, corner_hz: float, rng: np.random.Generator) -> np.ndarray:
    """Low-passed white noise (2nd-order Butterworth at `corner_hz`), RMS `rms` per joint."""
    from scipy import signal

    b, a = signal.butter(2, corner_hz, fs=1.0 / dt)  # pyright: ignore[reportAssignmentType, reportGeneralTypeIssues] (the default output="ba")
    x = np.asarray(signal.lfilter(b, a, rng.standard_normal((steps + 2000, len(rms))), axis=0))[2000:]
    return x * (np.asarray(rms) / np.sqrt(np.mean(x**2, axis=0)))


def truth_model(setup: Setup, extra: tuple = ()) -> Model:
    """Every linear effect of the vocabulary (the absent ones at zero: one compiled simulation
    serves every linear hidden effect) plus the non-linear `extra` (a Delay or a Compliance)."""
    effects = []
    for name in ORDER:
        e = VOCABULARY[name]()
        if e.linear:
            effects.append(e)
    return Model(setup.structure, tuple(effects) + tuple(extra))


def simulate_case(
    setup: Setup,
    rate: int,
    excitation: str,
    params: dict,
    extra: tuple,
    seconds: float,
    rng_seed: int,
    disturbance: np.ndarray | None = None,
    nonlinear: tuple = (),
):
    """One run: returns the trajectory (numpy). `params` are the truth's linear parameters;
    `nonlinear` replaces effects of the truth (Cogging(order=...), Stribeck(vs=...)) by
    versions with other non-linear parameters (array fields: no recompilation)."""
    model = truth_model(setup, extra)
    for e in nonlinear:
        model = model.with_effect(e)
    full = {k: 0.0 for k in model.defaults()}
    full.update({k: v for k, v in params.items() if k in full})
    plant = Simulator(
        model,
        full,
        rate_hz=rate,
        actuator=setup.actuator,
        encoder=Encoder(step=setup.encoder_step),
        q0=jnp.asarray(setup.centre, float),
    )
    dt = 1.0 / rate
    steps = int(round(seconds * rate))
    rng = np.random.default_rng(rng_seed)
    d = np.zeros((steps, setup.n)) if disturbance is None else disturbance
    wrapped = Disturbed(plant, jnp.asarray(d))
    estimator = FilteredFirstDifference(dt=dt)
    if excitation == "multisine":
        controller = Impedance(setup.stiffness, setup.damping, estimator, setup.actuator.limit, setup.n)
        reference = MultiSine(setup.centre, setup.swing, seed=int(rng.integers(2**31)))
    elif excitation == "reaching":
        controller = Impedance(setup.stiffness, setup.damping, estimator, setup.actuator.limit, setup.n)
        reference = reaching(setup, seconds, rng)
    elif excitation == "steps":
        controller = Replay(jnp.asarray(step_schedule(setup, steps, dt, rng)))
        reference = Hold(np.asarray(setup.centre, float))
    else:
        raise ValueError(f"unknown excitation {excitation!r}: one of {', '.join(EXCITATIONS)}")
    return simulate(wrapped, controller, reference, seconds, key=jax.random.PRNGKey(rng_seed % 2**31))


# -- the calibration cases -----------------------------------------------------------------------
def seconds_at(rate: float) -> float:
    """The length of a calibration recording at `rate` [s]."""
    return 12.0 if rate >= FAST else 20.0


def check_rates(rates) -> tuple[int, ...]:
    """Sample rates a calibration may draw from [Hz]: whole numbers from 100 Hz (a slower
    recording is too coarse for the set's effects: a cogging or a mode needs samples) to 20 kHz."""
    out = tuple(int(r) for r in rates)
    bad = [r for r, o in zip(rates, out, strict=True) if o != r or not 100 <= o <= 20000]
    if not out or bad:
        raise ValueError(f"sample rates must be whole numbers of Hz from 100 to 20000 (got {list(rates)})")
    return out


def check_amplitude(amplitude: float) -> float:
    """A hidden effect's size: a share of the recorded torque's RMS, between 0 and 1."""
    if not 0 < amplitude < 1:
        raise ValueError(
            f"a hidden effect's amplitude is a fraction of the torque's RMS, between 0 and 1 (got {amplitude:g})"
        )
    return amplitude


def draw_condition(seed: int, hidden: str | None = None, rates: tuple = RATES, **overrides) -> dict:
    """The condition of case `seed` (overrides win), its rate drawn from `rates`. A hidden
    `compliance` is drawn only under the open-loop steps; an effect that does not apply to the
    axis (gravity) only on the arm."""
    rates = check_rates(rates)
    rng = np.random.default_rng([seed, 7])
    c = {
        "structure": str(rng.choice(STRUCTURES)),
        "rate": int(rng.choice(rates)),
        "excitation": str(rng.choice(EXCITATIONS)),
        "torque": str(rng.choice(TORQUES)),
        "hold": str(rng.choice(HOLDS)),
    }
    if hidden == "compliance":
        c["excitation"] = "steps"
    if hidden is not None and not applies(hidden, AXIS):
        c["structure"] = "arm"
    unknown = set(overrides) - set(c)
    if unknown:
        raise ValueError(f"unknown condition key(s) {sorted(unknown)}: {', '.join(c)}")
    c.update(overrides)
    check_rates((c["rate"],))
    for key, allowed in (("structure", STRUCTURES), ("excitation", EXCITATIONS), ("torque", TORQUES), ("hold", HOLDS)):
        if c[key] not in allowed:
            raise ValueError(f"condition {key}={c[key]!r}: one of {allowed}")
    if hidden == "compliance" and c["excitation"] != "steps":
        raise ValueError("a hidden compliance shows only under the open-loop steps (excitation='steps')")
    if hidden is not None and hidden not in VOCABULARY:
        raise ValueError(f"unknown effect {hidden!r}: one of {', '.join(ORDER)}")
    if hidden is not None and not applies(hidden, SETUPS[c["structure"]]):
        raise ValueError(f"{hidden} does not apply to the {c['structure']}")
    return c


def start_model(hidden: str | None) -> str:
    return ",".join(e for e in NOMINAL if e != hidden)


def case(seed: int, hidden: str | None = None, rates: tuple = RATES, amplitude: float = AMPLITUDE, **overrides) -> Case:
    """Calibration recording `seed`: nothing hidden (`hidden=None`) or one effect of the
    vocabulary hidden at `amplitude` of the torque (RMS; a delay by what it changes, at least 1 ms;
    a mode has its own size), its rate drawn from `rates`. Keyword overrides fix condition values
    (structure, rate, excitation, torque, hold)."""
    check_amplitude(amplitude)
    import time

    t_start = time.perf_counter()
    c = draw_condition(seed, hidden, rates, **overrides)
    setup = SETUPS[c["structure"]]
    rate, dt = c["rate"], 1.0 / c["rate"]
    seconds = seconds_at(rate)
    steps = int(round(seconds * rate))
    rng = np.random.default_rng([seed, 11])
    sim_seed = int(rng.integers(2**31))
    # the non-linear parameters of effects that have them, drawn per case (array fields)
    order = (
        float(np.round(2 * np.pi / rng.uniform(*setup.cogging_period)))
        if not setup.prismatic
        else float(2 * np.pi / rng.uniform(*setup.cogging_period))
    )
    nonlinear = (Cogging(order=order), Stribeck(vs=setup.stribeck_vs), Smooth(width=setup.smooth_width))
    extra: tuple = ()
    joint: int | None = None
    info: dict = {}
    if hidden == "compliance":
        f = float(rng.uniform(*COMPLIANCE_BAND) * rate)
        zeta = float(rng.uniform(*COMPLIANCE_ZETA))
        extra = (Compliance(f_hz=f, zeta=zeta),)
        info.update(f_hz=round(f, 3), zeta=round(zeta, 4))
    params = dict(setup.nominal)
    effect = None
    if hidden is not None and hidden not in ("delay", "compliance"):
        of_truth = {e.name: e for e in truth_model(setup).effects} | {e.name: e for e in nonlinear}
        effect = of_truth[hidden]
        owner = parameter_joints(setup, effect)
        if all(j is not None for j in owner.values()):
            joint = 1 if setup.n == 1 else [None, 1, 2][int(rng.integers(3))]
        if hidden in NOMINAL and hidden != "rigid":
            params.update({k: 0.0 for k in Model(setup.structure, hidden).defaults()})
        for r in effect.replaces:  # (smooth friction takes Coulomb's place in the truth; the start keeps it)
            params.update({k: 0.0 for k in Model(setup.structure, r).defaults()})
    # the disturbances are scaled on a first run without the hidden effect (or with it at its
    # default, for rigid: a plant needs an inertia)
    d_coloured = None
    first = simulate_case(setup, rate, c["excitation"], params, (), seconds, sim_seed, None, nonlinear)
    tau_rms = rms(np.asarray(first.tau))
    if c["torque"] == "coloured":
        level = float(rng.uniform(*COLOURED))
        corner = float(rng.uniform(*COLOURED_HZ))
        d_coloured = coloured(steps, dt, level * tau_rms, corner, rng)
        info.update(disturbance_fraction=round(level, 3), disturbance_corner_hz=round(corner, 2))
    traj = first
    if effect is not None:
        unit = {
            k: float(v) for k, v in zip(effect.names(setup.structure), effect.defaults(setup.structure), strict=True)
        }
        base = first
        if c["torque"] == "coloured":  # measure on the motion the disturbance shapes too
            base = simulate_case(setup, rate, c["excitation"], params, (), seconds, sim_seed, d_coloured, nonlinear)
        hp, _ = scale_hidden(setup, effect, unit, joint, base, amplitude, dt)
        for attempt in range(2):
            traj = simulate_case(
                setup, rate, c["excitation"], {**params, **hp}, extra, seconds, sim_seed, d_coloured, nonlinear
            )
            got = achieved(setup, effect, hp, traj, dt, joint)
            on = [i for i in range(setup.n) if joint is None or i == joint - 1]
            if attempt or all(abs(got[i] / amplitude - 1) <= TOLERANCE for i in on if got[i] > 0):
                break
            hp, _ = scale_hidden(setup, effect, hp, joint, traj, amplitude, dt)
        params = {**params, **hp}
        info["hidden_fraction"] = [round(g, 4) for g in got]
        info["distinct_fraction"] = round(distinct(setup, effect, hp, start_model(hidden), traj, dt, nonlinear), 4)
    elif hidden == "delay":  # sized on the motion without it, then once more on the motion with it
        base = (
            first
            if d_coloured is None
            else simulate_case(setup, rate, c["excitation"], params, (), seconds, sim_seed, d_coloured, nonlinear)
        )
        d = size_delay(np.asarray(base.tau), rate, amplitude)
        for attempt in range(2):
            extra = (Delay(seconds=d),)
            traj = simulate_case(setup, rate, c["excitation"], params, extra, seconds, sim_seed, d_coloured, nonlinear)
            got = delay_change(np.asarray(traj.tau), d, rate)
            if attempt or d <= DELAY_MIN or abs(got[-1] / amplitude - 1) <= TOLERANCE:
                break
            d = size_delay(np.asarray(traj.tau), rate, amplitude)
        info["delay_ms"] = round(d * 1e3, 3)
        info["hidden_fraction"] = [round(float(x), 4) for x in got[:-1]]  # what the late command changes, per joint
    elif extra or d_coloured is not None:
        traj = simulate_case(setup, rate, c["excitation"], params, extra, seconds, sim_seed, d_coloured, nonlinear)
    meta = {"calibration": f"seed {seed}", **setup.meta()}
    rec = from_trajectory(
        traj, rate, "manus2" if setup.name == "arm" else "axis", 131072 if setup.name == "arm" else None, meta
    )
    rec.qd = None  # a rig does not log true velocities
    rec.extra = {}
    if c["torque"] == "white":
        level = float(rng.uniform(*WHITE))
        rec.tau = rec.tau + rng.standard_normal(rec.tau.shape) * (level * rms(rec.tau))
        info["noise_fraction"] = round(level, 3)
    if c["hold"] == "not stated":
        rec.meta.pop("command_hold", None)
    rec.path = f"<calibration seed {seed}, hidden {hidden or 'nothing'}>"
    if hidden == "cogging":
        info["order"] = order
    if hidden == "stribeck":
        info["vs"] = setup.stribeck_vs
    if hidden == "smooth":
        info["width"] = setup.smooth_width
    truth = {k: float(v) for k, v in params.items() if float(v) != 0.0}
    cond = {"seed": seed, **c, **info}
    return Case(rec, start_model(hidden), hidden, joint, cond, truth, time.perf_counter() - t_start)


# -- the errors-in-variables case ------------------------------------------------------------------
PENDULUM = {"M1": 0.05, "b1": 0.004, "Fc1": 0.01, "gc1": 0.0, "gs1": 1.0}  # kg m², N·m·s/rad, N·m, N·m
PENDULUM_RATE = 200
PENDULUM_SECONDS = 25.0
PENDULUM_COUNTS = 4096


def pendulum(seed: int = 0) -> Case:
    """A vertical pendulum (one revolute axis, q = 0 hanging; gravity torque gs sin q with
    gs = m g l) swung open loop by a torque several times smaller than gravity's peak — two
    sinusoids near and below its natural frequency, so the swing grows to 1–2 rad — at 200 Hz
    with a 4096-count encoder: the position noise is large against the swing's accelerations
    (errors in the variables). Nothing is hidden; `truth` holds the true parameters."""
    import time

    t0 = time.perf_counter()
    rng = np.random.default_rng([seed, 13])
    s = Axis(n_joints=1)
    truth = dict(PENDULUM)
    truth["M1"] *= rng.uniform(0.8, 1.25)
    truth["gs1"] *= rng.uniform(0.8, 1.25)
    model = Model(s, "rigid,viscous,coulomb,gravity")
    plant = Simulator(
        model,
        truth,
        rate_hz=PENDULUM_RATE,
        actuator=Actuator(dac_bits=16),
        encoder=Encoder.counts_per_rev(PENDULUM_COUNTS),
        q0=jnp.zeros(1),
    )
    dt = 1.0 / PENDULUM_RATE
    steps = int(round(PENDULUM_SECONDS * PENDULUM_RATE))
    t = np.arange(steps) * dt
    w0 = math.sqrt(truth["gs1"] / truth["M1"])
    amp = truth["gs1"] * rng.uniform(0.10, 0.15)
    ph = rng.uniform(0, 2 * np.pi, 2)
    u = amp * (0.6 * np.sin(0.93 * w0 * t + ph[0]) + 0.4 * np.sin(0.71 * w0 * t + ph[1]))
    u *= np.clip(t / 2.0, 0, 1)
    traj = simulate(
        plant,
        Replay(jnp.asarray(u[:, None])),
        Hold(np.zeros(1)),
        PENDULUM_SECONDS,
        key=jax.random.PRNGKey(seed % 2**31),
    )
    rec = from_trajectory(
        traj, PENDULUM_RATE, "axis", PENDULUM_COUNTS, {"joints": "revolute", "calibration": f"pendulum {seed}"}
    )
    rec.qd = None
    rec.extra = {}
    rec.path = f"<calibration pendulum seed {seed}>"
    cond = {
        "seed": seed,
        "structure": "pendulum",
        "rate": PENDULUM_RATE,
        "excitation": "open-loop sinusoids",
        "torque": "exact",
        "hold": "stated",
        "swing_rad": round(float(np.max(np.abs(traj.q_true))), 3),
        "drive_over_gravity": round(float(np.max(np.abs(u)) / truth["gs1"]), 3),
    }
    return Case(
        rec,
        "rigid,viscous,coulomb,gravity",
        None,
        None,
        cond,
        {k: float(v) for k, v in truth.items()},
        time.perf_counter() - t0,
    )
