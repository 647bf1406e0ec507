"""The vocabulary of physical effects (docs/effects.md), each defined once.

An effect is the torque it adds on each joint in the *inverse-dynamics* sense: the motor must
supply it on top of the rest, so the equation of motion is

    τ_applied = Σ_effects torque(q, q̇, q̈; θ)          (τ_applied: the torque that reaches the joint)

The same `torque` serves the simulator (truth), the regressors (adaptation and fitting: for a
linear effect the regressor is ∂torque/∂θ, derived with `jax.jacfwd`, exact for a linear term)
and the diagnosis (what a missing effect leaves in a residual).

| name | torque on joint i | linear parameters | other parameters |
|---|---|---|---|
| rigid | H(q) q̈ + C(q, q̇) q̇ (structure) | a1, a2, a3 (manus2) / M_i (axis) | |
| viscous | b_i q̇_i | b_i | |
| coulomb | Fc_i sgn(q̇_i) | Fc_i | |
| stribeck | dFs_i exp(−(q̇_i/vs)²) sgn(q̇_i), dFs_i = Fs_i − Fc_i | dFs_i | vs |
| smooth | Fs_i tanh(q̇_i/w) (Coulomb's smooth alternative) | Fs_i | w [rad/s or m/s] |
| asymmetry | db_i |q̇_i| | db_i | |
| offset | off_i | off_i | |
| gravity | gc_i cos(q_i) + gs_i sin(q_i) | gc_i, gs_i | |
| cogging | Σ_N A_i sin(N q_i) + B_i cos(N q_i) | A_i, B_i per order | N [cycles/rev] (one or more) |
| delay | the commanded torque arrives d seconds late (one d, or one per joint) | | d [s] |
| compliance | a shaft spring between motor and link | | f [Hz], ζ, motor fraction |
| spring | k_i q_i (its preload is `offset`'s constant) | k_i | |
| coupling | c (bc v + Fcc sgn v + Jc c·q̈), v = c·q̇, c = e_I ± e_J (two joints together) | bc, Fcc, Jc | I, J, ± |

No effect's columns lie in the span of another's. `asymmetry` is the viscous coefficient that
differs by direction (b⁺ = b + db, b⁻ = b − db); a Coulomb level that differs by direction is
`coulomb` plus `offset` already (Fc⁺ = Fc + off, Fc⁻ = Fc − off while moving), so asymmetry has
no Coulomb column of its own. `stribeck` is offered only on top of `coulomb` (`requires`), with
a velocity scale from the data, so that it cannot be Coulomb under another name. `smooth`
is Coulomb friction with a finite width (its limit w → 0 is the sign): it is offered on
`coulomb` (`requires`) and in its place (`replaces`). A spring's
preload is a constant torque: `spring` brings `offset` with it (`brings`) when the model lacks it.

Each effect owns everything about itself (one definition, no tables keyed by effect name
elsewhere): its columns (`names`, `torque`), the search space of its non-linear parameter
derived from the recording (`space`, from a `Span`), its physical rules (`lower_bounds`,
`violations`), which joints it applies to (`applies`), what its evidence is plotted against
(`evidence`), its adaptation gain (`gain`) and the argument of its spec (`parse`). The vocabulary
(`VOCABULARY`) is the effect classes registered with `in_vocabulary`, in their order of definition.

Friction effects (coulomb, stribeck, asymmetry) are set-valued at q̇ = 0: the simulator treats
them implicitly (stiction: a joint at rest stays at rest while the other torques stay inside the
static level); `smooth` friction is not (an ordinary smooth torque). Adaptive control can ask
for a boundary layer instead of the sign: `boundary=φ` replaces sgn(v) by sat(v/φ).

Defaults are the thesis's values where it gives them (rigid, viscous, coulomb, the 39/rev
cogging order, the 1 ms delay, the 200 Hz shaft mode); the other amplitudes are illustrative
and say so.
"""

from __future__ import annotations

import math
import re
from typing import ClassVar, NamedTuple, TypeVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from manus.plants import fastmath
from manus.plants.errors import ModelError
from manus.plants.structures import Structure


def sign(v: Array, boundary: float = 0.0) -> Array:
    """sgn(v); with a boundary layer φ > 0, the saturated ramp clip(v/φ, −1, 1)."""
    if boundary > 0:
        return jnp.clip(v / boundary, -1.0, 1.0)
    return fastmath.sign(v)


def per_joint(prefix: str, s: Structure) -> tuple[str, ...]:
    return tuple(f"{prefix}{i + 1}" for i in range(s.n_joints))


UNITS = {  # (what a column multiplies its parameter by, prismatic joint): the parameter's unit
    ("", False): "N·m",
    ("", True): "N",
    ("q", False): "N·m/rad",
    ("q", True): "N/m",
    ("qd", False): "N·m·s/rad",
    ("qd", True): "N·s/m",
    ("qdd", False): "kg·m²",
    ("qdd", True): "kg",
}


def unit_of(motion: str, prismatic: bool) -> str:
    """A parameter's unit from what its column multiplies it by and its joint's kind."""
    return UNITS[motion, prismatic]


def _prismatic(s: Structure, name: str, prismatic: tuple[bool, ...] = ()) -> bool:
    """Whether the joint a parameter's name ends with (1-based) is prismatic (by `prismatic`, else
    the structure's kinds); False for no number."""
    m = re.search(r"(\d+)$", name)
    j = int(m.group(1)) - 1 if m else -1
    kinds = tuple(prismatic) or tuple(s.prismatic)
    return bool(kinds[j]) if 0 <= j < len(kinds) else False


def stack(p: dict, names: tuple[str, ...]) -> Array:
    return jnp.stack([jnp.asarray(p[k]) for k in names])


class Span(NamedTuple):
    """What the search space of an effect's non-linear parameter is derived from: the recording's
    timing, the positions it covers and how fast it moves. Arrays are per joint."""

    dt: float  # sample period [s]
    duration: float  # [s]
    travel: np.ndarray  # (n,) range of positions covered [rad or m]
    step: float  # the encoder grid [rad or m] (0: unknown)
    speed: np.ndarray  # (n,) a high speed of the motion (95th percentile of |q̇|)
    prismatic: tuple[bool, ...]  # per joint: a linear axis (positions in metres)
    resolution: float = 0.0  # the smallest speed the data resolve (an encoder count per filter time)
    band: float = math.inf  # the identification band [Hz]: torque above it is filtered away
    typical: np.ndarray | None = None  # (n,) a typical speed of the motion (median of |q̇|)
    # the same in actuator coordinates θ = N q where the structure has a transmission, else None
    actuators: Span | None = None

    def of(self, effect: Effect) -> Span:
        """The span in the coordinates `effect` acts on: the actuators' for an effect a
        transmission maps (`Effect.actuated`: a motor's friction searches its width among the
        motor's speeds, a geared joint's among speeds N times its own), else this one."""
        return self.actuators if self.actuators is not None and effect.actuated else self


class Effect(eqx.Module):
    """One physical effect. Configuration only (its non-linear parameters); no state."""

    name: ClassVar[str]
    # What the effect is, as the simulator, the fit and the diagnosis use it:
    linear: ClassVar[bool] = True  # a torque linear in its parameters: it has regressor columns
    inertial: ClassVar[bool] = False  # it holds the structure's inertia, H(q) q̈ + C(q, q̇) q̇ (+ g on a chain)
    dry: ClassVar[bool] = False  # dry friction: set-valued at rest (the simulator's implicit friction step)
    timing: ClassVar[bool] = False  # it delays the command instead of adding a torque
    modal: ClassVar[bool] = False  # a structural mode above the identification band: no columns, a spectrum
    # Which side of a compliant shaft it acts on: the motor (friction, cogging, offset) or
    # the link (inertia, gravity).
    side: ClassVar[str] = "motor"
    # Its torque is written on the joints' own coordinates even on the motor side (a coupling names
    # the joints it combines): a transmission does not map it (`Model.torque`).
    on_joints: ClassVar[bool] = False

    @property
    def actuated(self) -> bool:
        """Whether a transmission θ = N q maps it (`manus.plants.transmission`): a motor-side
        effect not written on the joints acts at (N q, N q̇, N q̈), its torque reaching the joints
        as Nᵀ τ, and its search space is the actuators' (`Span.of`)."""
        return self.side == "motor" and not self.on_joints

    requires: ClassVar[tuple[str, ...]] = ()  # offered only on top of these effects
    brings: ClassVar[tuple[str, ...]] = ()  # added with it when the model lacks them
    replaces: ClassVar[tuple[str, ...]] = ()  # offered in the place of these where the model holds them
    evidence: ClassVar[str] = "velocity"  # what a residual is plotted against to show it
    apart: ClassVar[str] = ""  # the motion that tells it from an effect it reads as on a recording
    gain: ClassVar[float] = 5.0  # the Slotine–Li adaptation gain of its parameters (thesis: Γ = 5)
    # What its columns multiply its parameters by: "" (nothing: they are torques), "q", "qd" or "qdd"
    motion: ClassVar[str] = ""

    def names(self, s: Structure) -> tuple[str, ...]:
        """Linear parameter names, in regressor column order."""
        return ()

    def units(self, s: Structure, prismatic: tuple[bool, ...] = ()) -> tuple[str, ...]:
        """Each linear parameter's unit: its joint's torque (N·m, or N on a prismatic joint: the
        joint is the name's trailing number, its kind `prismatic`'s, else the structure's) over
        what its column multiplies it by (`motion`)."""
        return tuple(unit_of(self.motion, _prismatic(s, k, prismatic)) for k in self.names(s))

    def defaults(self, s: Structure) -> tuple[float, ...]:
        return ()

    def torque(self, s: Structure, q, qd, qdd, p: dict, boundary: float = 0.0) -> Array:
        """Torque this effect adds on each joint, shape (n,)."""
        return jnp.zeros(s.n_joints, jnp.result_type(qd))

    @property
    def spec(self) -> str:
        """The text that `parse_effects` turns back into this effect."""
        return self.name

    def describe(self) -> dict:
        """Non-linear parameters, for reports."""
        return {}

    # -- what the effect knows about identification ---------------------------------------
    def applies(self, s: Structure, prismatic: tuple[bool, ...] = ()) -> str | None:
        """None when the effect can act on these joints, else why not."""
        return None

    def space(self, span: Span) -> tuple[Effect, ...]:
        """The values of its non-linear parameter worth trying on a recording (in order, for a
        grid search); () when it has none to search."""
        return ()

    def grow(self, span: Span) -> tuple[Effect, ...]:
        """For an effect already in the model: larger versions of it worth trying (cogging: one
        more order); () for most."""
        return ()

    def unresolved(self, span: Span) -> str | None:
        """When this value of its non-linear parameter, given by the user, is one the recording
        cannot show at all (a cogging period under one encoder step): why; None for most."""
        return None

    def edge(self, span: Span) -> str | None:
        """When this (searched) value lies on the edge of `space(span)`: what that means."""
        grid = self.space(span)
        if len(grid) < 3:
            return None
        if self.spec == grid[-1].spec:
            return f"{self.spec} lies on the upper edge of its search range ({grid[0].spec} to {grid[-1].spec})"
        if self.spec == grid[0].spec:
            return f"{self.spec} lies on the lower edge of its search range ({grid[0].spec} to {grid[-1].spec})"
        return None

    def lower_bounds(self, s: Structure) -> tuple[float, ...]:
        """The physical lower bound of each linear parameter (−inf: signed)."""
        return (-math.inf,) * len(self.names(s))

    def beyond_bounds(self, s: Structure, params: dict, std: dict | None = None) -> list[str]:
        """The linear parameters below their physical lower bound by more than two standard
        deviations."""
        std = std or {}
        out = []
        for k, lo in zip(self.names(s), self.lower_bounds(s), strict=True):
            v, sd = params.get(k), std.get(k)
            sd = sd if sd is not None and np.isfinite(sd) else 0.0
            if v is not None and np.isfinite(lo) and v + 2 * sd < lo:
                out.append(k)
        return out

    def violations(self, s: Structure, params: dict, std: dict | None = None) -> list[str]:
        """The physical rules the fitted parameters break (beyond two standard deviations)."""
        std = std or {}
        lows = dict(zip(self.names(s), self.lower_bounds(s), strict=True))
        return [
            f"{k} = {params[k]:.4g} ± {std.get(k) or 0:.2g} < {lows[k]:g}: {self.name} {self.rule}"
            for k in self.beyond_bounds(s, params, std)
        ]

    rule: ClassVar[str] = ""  # what the lower bounds mean, for `violations`

    @classmethod
    def parse(cls, arg: str) -> Effect:
        """This effect from the argument of its spec, `name:arg` ("" : none, the defaults); an
        effect with no argument of its own refuses any."""
        if arg:
            raise ModelError(f"effect {cls.name!r} takes no argument (got {arg!r})")
        return cls()


VOCABULARY: dict[str, type[Effect]] = {}  # the vocabulary of physical effects by name, in its order
EffectClass = TypeVar("EffectClass", bound=type[Effect])


def in_vocabulary(cls: EffectClass) -> EffectClass:
    """Register the effect class `cls` in `VOCABULARY` under its name; the vocabulary's order is the
    order of registration (each class below, as it is defined)."""
    if cls.name in VOCABULARY:
        raise ValueError(f"effect {cls.name!r} is in the vocabulary already")
    VOCABULARY[cls.name] = cls
    return cls


def _number(text: str, what: str) -> float:
    try:
        return float(text)
    except ValueError:
        raise ModelError(f"{what}: {text!r} is not a number") from None


def _positive(text: str, what: str) -> float:
    v = _number(text, what)
    if not (v > 0 and math.isfinite(v)):
        raise ModelError(f"{what}: {text!r} must be a positive number")
    return v


MAX_DELAY_S = 10.0  # a command delay longer than this is a mistake of units, not a plant's


def _two(s: Structure, manus2: tuple[float, float], axis: float, own: str = "") -> tuple[float, ...]:
    """Default values per joint: the thesis's on its MANUS-2 arm (`Structure.thesis_arm`), or the
    structure's own nominal values of the effect named `own` (a URDF's joints' <dynamics>:
    `Structure.nominal`) where it gives any, else the axis's for every joint."""
    if s.thesis_arm:
        return manus2
    given = tuple(s.nominal(own)) if own else ()
    return given if any(given) else (axis,) * s.n_joints


@in_vocabulary
class Rigid(Effect):
    """Inertia and Coriolis/centripetal torques of the structure."""

    name: ClassVar[str] = "rigid"
    inertial: ClassVar[bool] = True
    side: ClassVar[str] = "link"
    motion: ClassVar[str] = "qdd"

    def names(self, s):
        return s.rigid_names

    def units(self, s, prismatic=()):
        """A chain's standard (or base) parameters by their leading symbol (m: kg, mx: kg·m, an
        inertia or an armature: kg·m²); an inertia of the others' over its joint's acceleration."""
        if s.combinations is None:
            return super().units(s, prismatic)
        lead = lambda k: re.match(r"[A-Za-z]+", k)
        return tuple(
            {"m": "kg", "mx": "kg·m", "my": "kg·m", "mz": "kg·m"}.get(m.group(0) if (m := lead(k)) else "", "kg·m²")
            for k in s.rigid_names
        )

    def defaults(self, s):
        return s.rigid_defaults

    gain: ClassVar[float] = 0.2  # thesis App. C: Γ = 0.2 for the inertias
    evidence: ClassVar[str] = "acceleration"

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        return s.rigid_torque(q, qd, qdd, p)

    def violations(self, s, params, std=None):
        return s.violations(params)


@in_vocabulary
class Viscous(Effect):
    """Viscous friction b_i q̇_i [N·m·s/rad]; thesis §3.5: b = 0.222, 0.181."""

    name: ClassVar[str] = "viscous"
    motion: ClassVar[str] = "qd"
    apart: ClassVar[str] = "motion at several speeds"

    def names(self, s):
        return per_joint("b", s)

    rule: ClassVar[str] = "friction dissipates: b ≥ 0"

    def defaults(self, s):
        return _two(s, (0.222, 0.181), 1.5, self.name)  # a URDF: its damping; axis: b = 1.5 N·s/m, thesis eq. 4.1

    def lower_bounds(self, s):
        return (0.0,) * s.n_joints

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        return stack(p, self.names(s)) * qd


@in_vocabulary
class Coulomb(Effect):
    """Coulomb friction Fc_i sgn(q̇_i) [N·m]; thesis §3.5: Fc = 0.099, 0.139."""

    name: ClassVar[str] = "coulomb"
    apart: ClassVar[str] = "motion in both directions"
    dry: ClassVar[bool] = True

    def names(self, s):
        return per_joint("Fc", s)

    rule: ClassVar[str] = "friction opposes motion: Fc ≥ 0"

    def defaults(self, s):
        return _two(s, (0.099, 0.139), 0.5, self.name)  # a URDF: its friction

    def lower_bounds(self, s):
        return (0.0,) * s.n_joints

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        return stack(p, self.names(s)) * sign(qd, boundary)


@in_vocabulary
class Stribeck(Effect):
    """Static friction above the Coulomb level, fading with speed: dFs_i exp(−(q̇_i/vs)²) sgn(q̇_i).

    The thesis notes stiction but does not measure it: the defaults (dFs ≈ half of Fc,
    vs = 0.05 rad/s) are illustrative.
    """

    name: ClassVar[str] = "stribeck"
    apart: ClassVar[str] = "slow motion through the reversals"
    dry: ClassVar[bool] = True
    vs: Array = eqx.field(default=0.05, converter=jnp.asarray)  # Stribeck velocity [rad/s or m/s]
    requires: ClassVar[tuple[str, ...]] = ("coulomb",)
    rule: ClassVar[str] = "static friction is at least the Coulomb level: Fs ≥ Fc"
    GRID: ClassVar[int] = 24

    def names(self, s):
        return per_joint("dFs", s)

    def lower_bounds(self, s):
        return (0.0,) * s.n_joints

    def space(self, span):
        """vs from twice the smallest speed the data resolve up to the motion's high speed (its
        95th percentile): a larger vs leaves exp(−(q̇/vs)²) within a factor e of 1 over most of
        the motion, which is Coulomb friction under another name. (A quarter of that speed was
        the top until the calibration showed hidden levels at 0.75 of it landing on the edge.)"""
        top = float(np.max(span.speed))
        low = max(top * 5e-4, 2 * span.resolution, 1e-12)
        if not top > 2 * low:
            return ()
        return tuple(Stribeck(vs=float(v)) for v in np.geomspace(low, top, self.GRID))

    def defaults(self, s):
        return _two(s, (0.05, 0.07), 0.25)

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        return stack(p, self.names(s)) * jnp.exp(-((qd / self.vs) ** 2)) * sign(qd, boundary)

    @property
    def spec(self):
        return f"stribeck:{float(self.vs):.4g}"

    @classmethod
    def parse(cls, arg):
        """`stribeck:VS`, the Stribeck velocity [rad/s or m/s]."""
        return cls(vs=_positive(arg, "Stribeck velocity")) if arg else cls()

    def describe(self):
        return {"vs": float(self.vs)}


@in_vocabulary
class Smooth(Effect):
    """Friction smooth at zero speed: Fs_i tanh(q̇_i / w), one width w [rad/s or m/s] for every
    joint, found from the data (`space`). Real friction rises over a finite speed (a sigmoid over
    ±0.1–0.2 rad/s on a 7-joint arm's joints; DFKI's double pendulum: cf atan(100 q̇), w ≈
    0.01 rad/s); Coulomb's sign is its limit w → 0. It is not set-valued: an ordinary smooth
    torque for the simulator (no stiction), non-decreasing in q̇ (adaptive control keeps its
    passivity).

    Smooth friction is an alternative to `coulomb` (`replaces`): with both in a model their
    columns are nearly one as w → 0. It refines Coulomb friction the model holds (`requires`:
    from a model without it Coulomb's sign comes first, as it should where a saturating law
    would take the viscous term's share too, as on EMPS): diagnose judges smooth on top of it
    (does the recording show a finite width beyond the sign?) and proposes it in Coulomb's
    place unless Coulomb's sign still predicts held-out data significantly better together
    with it (`manus.adaptive.diagnosis.candidates`). A width on the lower edge of the search
    is Coulomb's sign: the recording does not resolve a width. Illustrative
    defaults."""

    name: ClassVar[str] = "smooth"
    apart: ClassVar[str] = "slow reversals (speeds within a few widths of zero)"
    width: Array = eqx.field(default=0.1, converter=jnp.asarray)  # w [rad/s or m/s]
    requires: ClassVar[tuple[str, ...]] = ("coulomb",)
    replaces: ClassVar[tuple[str, ...]] = ("coulomb",)
    rule: ClassVar[str] = "friction opposes motion: Fs ≥ 0"
    STEP: ClassVar[float] = 1.15  # ratio of neighbouring widths of `space`
    MAX_GRID: ClassVar[int] = 40
    TOP: ClassVar[float] = 0.5  # the widest width tried, as a fraction of the motion's high speed

    def names(self, s):
        return per_joint("Fs", s)

    def defaults(self, s):
        return _two(s, (0.1, 0.12), 0.5)

    def lower_bounds(self, s):
        return (0.0,) * s.n_joints

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        return stack(p, self.names(s)) * jnp.tanh(qd / self.width)

    def space(self, span):
        """w from twice the smallest speed the data resolve (an encoder count per filter time:
        below it tanh is the sign on every sample) up to `TOP` of the motion's high speed (95th
        percentile of |q̇|; a wider law reaches less than tanh 2 of its level over most of the
        motion, nearly linear: viscous friction under another name), on a geometric grid `STEP`
        apart (at most `MAX_GRID` values)."""
        top = self.TOP * float(np.max(span.speed))
        low = max(2 * span.resolution, top * 1e-3, 1e-12)
        if not top > 2 * low:
            return ()
        count = int(np.clip(np.ceil(np.log(top / low) / np.log(self.STEP)) + 1, 3, self.MAX_GRID))
        return tuple(Smooth(width=float(v)) for v in np.geomspace(low, top, count))

    def edge(self, span):
        grid = self.space(span)
        if len(grid) >= 3 and self.spec == grid[0].spec:
            return (
                f"{self.spec} lies on the lower edge of its search range ({grid[0].spec} to {grid[-1].spec}): "
                "a width the recording does not resolve, Coulomb's sign"
            )
        return super().edge(span)

    @property
    def spec(self):
        return f"smooth:{float(self.width):.4g}"

    @classmethod
    def parse(cls, arg):
        """`smooth:W`, the width [rad/s or m/s]."""
        return cls(width=_positive(arg, "smooth friction width")) if arg else cls()

    def describe(self):
        return {"width": float(self.width)}


@in_vocabulary
class Asymmetry(Effect):
    """A viscous coefficient that differs by direction: db_i |q̇_i| (b⁺ = b + db, b⁻ = b − db).

    A Coulomb level that differs by direction needs no column here: `coulomb` plus `offset`
    already give Fc ± off while the joint moves. Illustrative defaults.
    """

    name: ClassVar[str] = "asymmetry"
    motion: ClassVar[str] = "qd"
    apart: ClassVar[str] = "motion in both directions"

    def names(self, s):
        return per_joint("db", s)

    def defaults(self, s):
        return _two(s, (0.05, 0.04), 0.3)

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        return stack(p, self.names(s)) * jnp.abs(qd)


@in_vocabulary
class Offset(Effect):
    """A constant torque off_i (amplifier or sensor bias; illustrative defaults)."""

    name: ClassVar[str] = "offset"

    def names(self, s):
        return per_joint("off", s)

    def defaults(self, s):
        return _two(s, (0.05, -0.04), 0.2)

    evidence: ClassVar[str] = "time"

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        return stack(p, self.names(s)) + 0 * qd


@in_vocabulary
class Gravity(Effect):
    """A tilted work plane: gc_i cos(q_i) + gs_i sin(q_i) on each absolute angle.

    Defaults: a plane tilted by about 1° (illustrative).
    """

    name: ClassVar[str] = "gravity"
    apart: ClassVar[str] = "a wider swing"
    side: ClassVar[str] = "link"

    def names(self, s):
        return per_joint("gc", s) + per_joint("gs", s)

    def defaults(self, s):
        return _two(s, (0.07, 0.05), 0.2) + _two(s, (0.02, -0.02), 0.0)

    evidence: ClassVar[str] = "position"

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        n = s.n_joints
        th = stack(p, self.names(s))
        return th[:n] * fastmath.cos(q) + th[n:] * fastmath.sin(q)

    def applies(self, s, prismatic=()):
        if s.rigid_gravity:  # a structure whose rigid effect holds gravity says why
            return s.rigid_gravity
        if any(prismatic):
            return (
                "gravity is a cos/sin of a joint angle: it does not apply to a prismatic axis (a constant load "
                "there is an offset)"
            )
        return None


@in_vocabulary
class Spring(Effect):
    """A spring: k_i q_i (a return spring, a cable, a gravity compensator). Its preload is a
    constant torque, `offset`'s column, so a spring brings `offset` with it. k ≥ 0: it pulls
    back toward its rest position. Illustrative defaults."""

    name: ClassVar[str] = "spring"
    motion: ClassVar[str] = "q"
    apart: ClassVar[str] = "a wider swing"
    side: ClassVar[str] = "link"
    brings: ClassVar[tuple[str, ...]] = ("offset",)
    evidence: ClassVar[str] = "position"
    rule: ClassVar[str] = "a spring pulls back toward its rest position: k ≥ 0"

    def names(self, s):
        return per_joint("k", s)

    def defaults(self, s):
        return _two(s, (0.2, 0.15), 20.0)

    def lower_bounds(self, s):
        return (0.0,) * s.n_joints

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        return stack(p, self.names(s)) * q


@in_vocabulary
class Cogging(Effect):
    """Position-periodic torque Σ_N A_i sin(N q_i) + B_i cos(N q_i), N cycles per revolution
    (for a prismatic axis N is in radians per metre: the period is 2π/N metres).

    Thesis App. A: the MANUS-2 motors show 39/rev cogging (39 cogs), 6/rev torque ripple and a
    1/rev position-dependent friction; the order N selects which, and one effect can hold
    several orders at once (`cogging:39+6`): the first order's parameters are A_i, B_i, the k-th
    order's A_i_k, B_i_k (k = 2, 3, …, in the order of `orders`). Amplitudes illustrative.
    """

    name: ClassVar[str] = "cogging"
    apart: ClassVar[str] = "travel over several of its periods"
    evidence: ClassVar[str] = "position"
    order: Array = eqx.field(default=39.0, converter=jnp.asarray)  # cycles per revolution
    # further orders, held at once: arrays (their values are not part of a compiled function's
    # identity; only how many there are is)
    more: tuple = eqx.field(default=(), converter=lambda xs: tuple(jnp.asarray(x, float) for x in xs))
    MAX_ORDER: ClassVar[int] = 200  # rotary orders searched: 2 periods over the travel .. this
    MIN_COUNTS: ClassVar[int] = 16  # a period spans at least this many encoder counts
    PERIODS: ClassVar[float] = 1.5  # a period repeats at least this often over the travel

    @property
    def orders(self) -> tuple:
        return (self.order, *self.more)

    def names(self, s):
        out = per_joint("A", s) + per_joint("B", s)
        for k in range(2, len(self.more) + 2):  # by position: a name must not depend on a traced value
            out += tuple(f"A{i + 1}_{k}" for i in range(s.n_joints)) + tuple(f"B{i + 1}_{k}" for i in range(s.n_joints))
        return out

    def defaults(self, s):
        first = _two(s, (0.02, 0.015), 0.2) + _two(s, (0.01, -0.01), 0.1)
        return first + (0.0,) * (2 * s.n_joints * len(self.more))

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        n = s.n_joints
        th = stack(p, self.names(s))
        total = 0 * q
        for k, N in enumerate(self.orders):
            a, b = th[2 * n * k : 2 * n * k + n], th[2 * n * k + n : 2 * n * (k + 1)]
            total = total + a * fastmath.sin(N * q) + b * fastmath.cos(N * q)
        return total

    @property
    def spec(self):
        return "cogging:" + "+".join(f"{float(N):.6g}" for N in self.orders)

    @classmethod
    def parse(cls, arg):
        """`cogging:N`, or several orders at once `cogging:39+6` [cycles/rev, or rad/m]."""
        if not arg:
            return cls()
        orders = [_positive(x, "cogging order") for x in arg.split("+")]
        return cls(order=orders[0], more=tuple(orders[1:]))

    def describe(self):
        out: dict = {"order": float(self.order)}
        if self.more:
            out["orders"] = [float(N) for N in self.orders]
        return out

    def _grid(self, span: Span) -> np.ndarray:
        """Orders worth trying: a period shorter than two thirds of the largest travel (so that
        a cogging is not a smooth function of position over the stroke) and longer than
        `MIN_COUNTS` encoder counts and than what the joints cover in one period of the
        identification band at their typical (median) speed: a shorter period ripples faster
        than the band for most of the motion, its torque filtered away except near standstill,
        where its columns are a flexible function of the slow moments rather than a
        position-periodic torque (on EMPS a 0.88 mm period, 2.85 per motor revolution, fitted
        0.85 % of the torque there and nothing on the PULSES recording); rotary joints: integers
        up to `MAX_ORDER` cycles/rev."""
        travel = float(np.max(span.travel))
        if not travel > 0:
            return np.zeros(0)
        longest = travel / self.PERIODS
        shortest = self.MIN_COUNTS * span.step if span.step else travel / 2000
        if span.typical is not None and np.isfinite(span.band) and span.band > 0:
            shortest = max(shortest, float(np.max(span.typical)) / span.band)
        if any(span.prismatic):
            if not longest > 2 * shortest:
                return np.zeros(0)
            return 2 * np.pi / np.geomspace(longest, shortest, 160)
        lo = max(2, int(np.ceil(2 * np.pi / longest)))
        hi = min(self.MAX_ORDER, int(2 * np.pi / shortest))
        return np.arange(lo, hi + 1, dtype=float)

    def space(self, span):
        return tuple(Cogging(order=float(N)) for N in self._grid(span))

    def grow(self, span: Span) -> tuple[Effect, ...]:
        """This cogging plus one more order (several at once: the 39/rev cogging and the 6/rev
        ripple), orders it already holds left out."""
        held = [float(N) for N in self.orders]
        return tuple(
            Cogging(order=self.order, more=(*self.more, float(N)))
            for N in self._grid(span)
            if min(abs(float(N) - h) for h in held) > 0.5 * min(1.0, float(N) * 1e-3 + 0.5)
        )

    def unresolved(self, span):
        shortest = 2 * np.pi / max(float(N) for N in self.orders)
        if span.step and shortest < span.step:
            return (
                f"{self.spec}: a period of {shortest:.3g}, under one encoder step ({span.step:.3g}): "
                "no recording by this encoder can show it"
            )
        return None

    def edge(self, span):
        grid = self._grid(span)
        N = float(self.orders[-1])
        if grid.size >= 3 and (np.isclose(N, grid[0]) or np.isclose(N, grid[-1])):
            return (
                f"order {N:.6g} lies on the edge of its search range ({grid[0]:.6g} to {grid[-1]:.6g}): "
                "a period as long as half the travel or as short as a few encoder counts"
            )
        return None


@in_vocabulary
class Delay(Effect):
    """The commanded torque arrives `seconds` late (thesis §3.2: the amplifier's 1 ms): one
    delay for every joint, or one per joint (a tuple: joints driven by different amplifiers or
    buses). A recording's search first tries one delay for all joints (`space`); once the model
    holds one, a joint's delay may differ from the others' (`grow`: one joint at a time)."""

    name: ClassVar[str] = "delay"
    linear: ClassVar[bool] = False
    timing: ClassVar[bool] = True
    evidence: ClassVar[str] = "shift"
    seconds: float | tuple[float, ...] = eqx.field(default=0.001, static=True)

    def per_joint(self, n: int) -> np.ndarray:
        """The delay of each of `n` joints [s], (n,)."""
        d = np.asarray(self.seconds, float)
        if d.ndim and d.size != n:
            raise ModelError(f"{self.spec}: {d.size} delays for {n} joints")
        return np.broadcast_to(d, (n,)).copy()

    @property
    def spec(self):
        if isinstance(self.seconds, tuple):
            return "delay:" + "/".join(f"{d * 1e3:.4g}ms" for d in self.seconds)
        return f"delay:{self.seconds * 1e3:.4g}ms"

    @classmethod
    def parse(cls, arg):
        """`delay:2ms` or `delay:0.002` [s], or one per joint `delay:1ms/3ms`; at most `MAX_DELAY_S`."""
        if not arg:
            return cls()
        values = []
        for part in arg.split("/"):  # one delay, or one per joint: delay:1ms/3ms
            m = re.fullmatch(r"\s*([0-9.eE+-]+)\s*(ms|s)?\s*", part)
            if not m:
                raise ModelError(f"delay: {part!r} is not a duration such as 1ms or 0.001 (per joint: 1ms/3ms)")
            value = _number(m.group(1), "delay")
            values.append(value * 1e-3 if m.group(2) == "ms" else value)
        if any(v < 0 for v in values):
            raise ModelError(f"delay: {arg!r}: a delay cannot be negative")
        if not all(v <= MAX_DELAY_S for v in values):
            raise ModelError(
                f"delay: {arg!r}: longer than {MAX_DELAY_S:g} s, no amplifier's or bus's delay "
                "(a delay in milliseconds is written 2ms)"
            )
        return cls(seconds=values[0] if len(values) == 1 else tuple(values))

    def describe(self):
        if isinstance(self.seconds, tuple):
            return {"delay_ms": [round(d * 1e3, 6) for d in self.seconds]}
        return {"delay_ms": self.seconds * 1e3}

    @staticmethod
    def _grid(span: Span) -> list[float]:
        """The delays of `space` [s]."""
        top = max(10 * span.dt, min(0.02 * span.duration, 0.1))
        fine = np.arange(0.0, min(5 * span.dt, top), span.dt / 10)
        coarse = np.geomspace(5 * span.dt, top, 30) if top > 5 * span.dt else np.zeros(0)
        return [float(d) for d in np.unique(np.round(np.r_[fine, coarse], 9))]

    def space(self, span):
        """0 to a sensible fraction of the record (2 %, at most 100 ms, at least ten samples):
        tenths of a sample up to five samples, then a geometric grid."""
        return tuple(Delay(seconds=d) for d in self._grid(span))

    def grow(self, span):
        """One joint's delay other than it is now, the others kept: for each joint, every value
        of `space` but its own (so a loop refines the joints' delays one at a time)."""
        n = len(span.travel)
        if n < 2:
            return ()
        d = self.per_joint(n)
        return tuple(
            Delay(seconds=tuple(v if i == j else float(d[i]) for i in range(n)))
            for j in range(n)
            for v in self._grid(span)
            if v != d[j]
        )

    def edge(self, span):
        if not isinstance(self.seconds, tuple):
            return super().edge(span)
        top = self._grid(span)[-1]
        at = [i + 1 for i, d in enumerate(self.seconds) if d >= top]
        if at:  # (a joint at 0 while the others are late is a value, not an edge)
            joints = ", ".join(map(str, at))
            return f"{self.spec}: joint {joints} lies on the upper edge of its search range ({top * 1e3:.4g} ms)"
        return None


@in_vocabulary
class Compliance(Effect):
    """A structural mode: the motor drives the link through a shaft spring and damper.

    Thesis Fig. 4-16 (1-DOF form): motor mass m = 0.1, link mass m2 = 0.9, shaft k2 = 170000,
    b2 = 2.0. Here the mode is given by its undamped frequency f = √(k2 (1/m + 1/m2)) / 2π =
    218.7 Hz, the shaft's damping ratio ζ = b2 / (2 √(k2 μ)) with μ the reduced mass
    (0.0081 for b2 = 2.0), and the motor's fraction r = m/(m + m2) = 0.1 of the inertia.
    The encoder sits on the motor.
    """

    name: ClassVar[str] = "compliance"
    linear: ClassVar[bool] = False
    modal: ClassVar[bool] = True
    evidence: ClassVar[str] = "frequency"
    f_hz: Array = eqx.field(default=218.7, converter=jnp.asarray)
    zeta: Array = eqx.field(default=0.0081, converter=jnp.asarray)
    motor_fraction: float = eqx.field(default=0.1, static=True)

    def shaft(self, inertia: ArrayLike) -> tuple[Array, Array]:
        """Shaft stiffness and damping for a joint of total inertia `inertia`."""
        mu = inertia * self.motor_fraction * (1 - self.motor_fraction)
        w = 2 * jnp.pi * self.f_hz
        return w**2 * mu, 2 * self.zeta * w * mu

    @property
    def spec(self):
        return f"compliance:{float(self.f_hz):g}"

    @classmethod
    def parse(cls, arg):
        """`compliance:F`, the mode's frequency [Hz] (`218.7` or `218.7hz`)."""
        return cls(f_hz=_positive(arg.lower().removesuffix("hz"), "compliance frequency")) if arg else cls()

    def describe(self):
        return {"f_hz": float(self.f_hz), "zeta": float(self.zeta), "motor_fraction": self.motor_fraction}


@in_vocabulary
class Coupling(Effect):
    """Friction and rotor inertia on a combination of two joints, v = q̇_i ± q̇_j: a motor that
    turns with both (a differential wrist, θ = q5 + q6; the elbow motor of an arm in absolute
    angles, θ2 = q2 − q1). With c = e_i ± e_j its torque on the joints is (virtual work)

        c (bc v + Fcc sgn v + Jc c·q̈),    v = c·q̇

    bc, Fcc, Jc ≥ 0 (friction dissipates, an inertia is positive). Which joints and which sign is
    its non-linear parameter: `space` lists every pair both ways, and the search picks one.
    `coupling:2-1` is q2 − q1, `coupling:5+6` is q5 + q6 (joints 1-based). Its torque is written on
    the joints (`on_joints`): a stated transmission (`manus.plants.transmission`) maps the other
    motor-side effects, and a coupling is what diagnose proposes where none was stated. The
    simulator takes its Coulomb term as an ordinary torque (no stiction) and not its inertia
    (the structure's H(q) holds the simulated inertia). Illustrative defaults."""

    name: ClassVar[str] = "coupling"
    on_joints: ClassVar[bool] = True
    apart: ClassVar[str] = "the two joints moving apart and together"
    rule: ClassVar[str] = "friction dissipates and an inertia is positive: bc, Fcc, Jc ≥ 0"
    first: Array = eqx.field(default=1, converter=jnp.asarray)  # i (0-based)
    second: Array = eqx.field(default=0, converter=jnp.asarray)  # j (0-based)
    sign: Array = eqx.field(default=-1.0, converter=jnp.asarray)  # ±1: v = q̇_i ± q̇_j

    def names(self, s):
        return ("bc", "Fcc", "Jc")

    def units(self, s, prismatic=()):
        """bc over the combined velocity, Fcc a torque, Jc an inertia (on revolute joints)."""
        return (unit_of("qd", False), unit_of("", False), unit_of("qdd", False))

    def defaults(self, s):
        return (0.05, 0.05, 0.0)

    def lower_bounds(self, s):
        return (0.0, 0.0, 0.0)

    def combination(self, n: int) -> Array:
        """c = e_i ± e_j, (n,)."""
        k = jnp.arange(n)
        return (k == self.first).astype(float) + self.sign * (k == self.second)

    def torque(self, s, q, qd, qdd, p, boundary=0.0):
        c = self.combination(s.n_joints).astype(jnp.result_type(qd, float))
        v = c @ qd
        return c * (p["bc"] * v + p["Fcc"] * sign(v, boundary) + p["Jc"] * (c @ qdd))

    def applies(self, s, prismatic=()):
        if s.n_joints < 2:
            return "a coupling combines two joints: this structure has one"
        if max(self.joints) > s.n_joints:
            return f"{self.spec}: joint {max(self.joints)} of a structure with {s.n_joints} joints"
        return None

    def space(self, span):
        """Every pair of joints i < j, as q̇_j − q̇_i and as q̇_i + q̇_j."""
        n = len(span.travel)
        return tuple(
            Coupling(first=a, second=b, sign=sg)
            for i in range(n)
            for j in range(i + 1, n)
            for a, b, sg in ((j, i, -1.0), (i, j, 1.0))
        )

    def edge(self, span):
        return None  # (pairs of joints: no range with edges)

    @property
    def joints(self) -> tuple[int, int]:
        """(i, j), 1-based."""
        return int(self.first) + 1, int(self.second) + 1

    @property
    def spec(self):
        i, j = self.joints
        return f"coupling:{i}{'+' if float(self.sign) > 0 else '-'}{j}"

    @classmethod
    def parse(cls, arg):
        """`coupling:I-J` (q_I − q_J) or `coupling:I+J` (q_I + q_J), joints 1-based; `coupling`
        alone is q2 − q1."""
        if not arg:
            return cls()
        m = re.fullmatch(r"\s*(\d+)\s*([+-])\s*(\d+)\s*", arg)
        if not m or int(m.group(1)) < 1 or int(m.group(3)) < 1 or m.group(1) == m.group(3):
            raise ModelError(f"coupling: {arg!r} is not two joints such as 2-1 (q2 − q1) or 5+6 (q5 + q6)")
        return cls(first=int(m.group(1)) - 1, second=int(m.group(3)) - 1, sign=1.0 if m.group(2) == "+" else -1.0)

    def describe(self):
        i, j = self.joints
        op = "+" if float(self.sign) > 0 else "−"
        return {"joints": [i, j], "combination": f"q{i} {op} q{j}"}


def is_dry(e: Effect) -> bool:
    """Dry friction: a torque set-valued at rest."""
    return e.dry


def is_load(e: Effect) -> bool:
    """A smooth load: a linear torque that is neither the inertia nor dry friction."""
    return e.linear and not (e.inertial or e.dry)


ORDER = tuple(
    VOCABULARY
)  # rigid, viscous, coulomb, stribeck, smooth, asymmetry, offset, gravity, spring, cogging, delay, compliance, coupling


def parse_effect(text: str) -> Effect:
    """One effect from its spec: `name` or `name:value` (cogging:39, stribeck:0.02,
    delay:2ms or delay:0.002, one delay per joint delay:1ms/3ms, compliance:218.7); each effect
    parses its own value (`Effect.parse`)."""
    name, _, arg = text.strip().partition(":")
    name = name.strip().lower()
    if name not in VOCABULARY:
        raise ModelError(f"unknown effect {name!r}: the vocabulary is {', '.join(ORDER)}")
    return VOCABULARY[name].parse(arg)


def parse_effects(text: str | list[str] | tuple) -> tuple[Effect, ...]:
    """`"rigid,viscous,coulomb"` -> effects in the vocabulary's order, each at most once."""
    items = text.split(",") if isinstance(text, str) else list(text)
    effects = [
        e if isinstance(e, Effect) else parse_effect(e) for e in items if not (isinstance(e, str) and not e.strip())
    ]
    if not effects:
        raise ModelError("empty effect list: name at least one of " + ", ".join(ORDER))
    seen = [e.name for e in effects]
    dup = sorted({n for n in seen if seen.count(n) > 1})
    if dup:
        raise ModelError(f"effect {dup[0]!r} given twice")
    return tuple(sorted(effects, key=lambda e: ORDER.index(e.name)))


class Model(eqx.Module):
    """A structure plus a tuple of effects. Its linear parameters are the effects' in order;
    its regressor is the stack of their columns."""

    structure: Structure
    effects: tuple[Effect, ...]

    def __init__(self, structure: Structure, effects):
        self.structure = structure
        self.effects = parse_effects(effects) if isinstance(effects, str) else tuple(effects)

    # -- bookkeeping ---------------------------------------------------------------------
    @property
    def n_joints(self) -> int:
        return self.structure.n_joints

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(k for e in self.effects for k in e.names(self.structure))

    def units(self, prismatic: tuple[bool, ...] = ()) -> dict[str, str]:
        """Each linear parameter's unit (`Effect.units`), by name."""
        return {
            k: u
            for e in self.effects
            for k, u in zip(e.names(self.structure), e.units(self.structure, prismatic), strict=True)
        }

    def defaults(self) -> dict[str, float]:
        s = self.structure
        return {k: v for e in self.effects for k, v in zip(e.names(s), e.defaults(s), strict=True)}

    def get(self, name: str) -> Effect | None:
        return next((e for e in self.effects if e.name == name), None)

    def violations(self, params: dict, std: dict | None = None) -> list[str]:
        """The physical rules `params` break, each effect's own (beyond two `std` where given)."""
        return [v for e in self.effects for v in e.violations(self.structure, params, std)]

    def has(self, name: str) -> bool:
        return self.get(name) is not None

    def with_effect(self, effect: Effect) -> Model:
        kept = tuple(e for e in self.effects if e.name != effect.name)
        return Model(self.structure, parse_effects(kept + (effect,)))

    def without(self, name: str) -> Model:
        return Model(self.structure, tuple(e for e in self.effects if e.name != name))

    @property
    def spec(self) -> str:
        return ",".join(e.spec for e in self.effects)

    @property
    def effect_names(self) -> list[str]:
        return [e.name for e in self.effects]

    def vector(self, params: dict) -> Array:
        """θ as a vector in regressor column order."""
        return stack(params, self.names)

    def unvector(self, theta) -> dict:
        return {k: theta[i] for i, k in enumerate(self.names)}

    # -- torques and regressors -----------------------------------------------------------
    def torque(self, q, qd, qdd, params: dict, boundary: float = 0.0, only=None, side=None) -> Array:
        """Σ of the linear effects' torques, shape (n,); only the effects `only(effect)` accepts
        (e.g. `is_dry`, `is_load`) and acting on `side` ("motor" or "link") when given. Where the
        structure has a transmission θ = N q (`manus.plants.transmission`), the motor-side effects
        act on the actuators: evaluated at (N q, N q̇, N q̈), their torque reaches the joints as Nᵀ τ."""
        total = jnp.zeros(self.structure.n_joints, jnp.result_type(qd, float))
        for e in self.effects:
            if e.linear and (only is None or only(e)) and (side is None or e.side == side):
                total = total + self.effect_torque(e, q, qd, qdd, params, boundary)
        return total

    def effect_torque(self, e: Effect, q, qd, qdd, params: dict, boundary: float = 0.0) -> Array:
        """The torque of the effect `e` on the joints, (n,): a motor-side effect's on the actuators
        θ = N q where the structure has a transmission (`manus.plants.transmission`), mapped by Nᵀ."""
        s, N = self.structure, self.structure.transmission
        if N is not None and e.actuated:
            return N.acting(e.torque, s, q, qd, qdd, params, boundary)
        return e.torque(s, q, qd, qdd, params, boundary)

    def regressor(self, q, qd, qdd, boundary: float = 0.0) -> Array:
        """Y(q, q̇, q̈) with torque = Y θ, shape (n, P): ∂torque/∂θ, exact for linear effects."""
        theta0 = jnp.zeros(len(self.names), jnp.result_type(qd, float))
        return jax.jacfwd(lambda th: self.torque(q, qd, qdd, self.unvector(th), boundary))(theta0)
