"""Every velocity estimator by name: `NAMES`, `make`, and the knob each one tunes (`KNOBS`).

    est = estimators.make("kalman_ca", dt=1e-3, step=2 * math.pi / 131072)
    est = estimators.make("kalman_model", n_joints=2, model=Model(Manus2(), "rigid,viscous,coulomb"),
                          params={"a1": 0.35}, q=1e-4)
    state = est.init(q0); state, e = est.step(state, q, tau_prev)   # e.q, e.qd[, e.qdd]

Defaults are the thesis's where it has them: λ = 188.5 rad/s for the filtered first difference,
measurement noise Δ²/12 of an encoder of step Δ = 2π/131072 rad (`step=` for another one), and
the Kalman filters' and observers' bandwidths at the noise of the thesis's filter
(`manus.estimators.linear`). The model-based estimators take a `manus.plants.effects.Model` (default: the
thesis's nominal model rigid,viscous,coulomb of the structure, manus2 for 2 joints, axis
otherwise) and its parameters (default `Model.defaults()`), which `with_params` replaces in the
state.
"""

from __future__ import annotations

import jax.numpy as jnp

from manus.estimators.base import Estimator, FilteredFirstDifference, FirstDifference
from manus.estimators.dynamics import ModelDynamics
from manus.estimators.foaw import Foaw
from manus.estimators.kalman import KinematicKalman
from manus.estimators.linear import THESIS_STEP, quantization_variance
from manus.estimators.luenberger import Luenberger
from manus.estimators.model_kalman import ModelKalman
from manus.estimators.sliding import Levant
from manus.plants.catalog import structure_named
from manus.plants.effects import Model
from manus.plants.errors import ManusError

NOMINAL_MODEL = "rigid,viscous,coulomb"  # the thesis's nominal model (§3.5)

NAMES = (
    "first_difference",
    "filtered_first_difference",
    "kalman_cv",
    "kalman_ca",
    "kalman_model",
    "luenberger",
    "luenberger_model",
    "levant",
    "foaw",
)
MODEL_BASED = ("kalman_model", "luenberger_model")

# The settings `make` takes for each (every one has a default).
_MODEL_SETTINGS = ("model", "params", "structure", "boundary")
SETTINGS: dict[str, tuple[str, ...]] = {
    "first_difference": (),
    "filtered_first_difference": ("corner",),
    "kalman_cv": ("q", "steady"),
    "kalman_ca": ("q", "steady"),
    "kalman_model": ("q",) + _MODEL_SETTINGS,
    "luenberger": ("bandwidth",),
    "luenberger_model": ("bandwidth",) + _MODEL_SETTINGS,
    "levant": ("lipschitz",),
    "foaw": ("d", "window"),
}

# The knob `--tune` searches, as (knob, low, high, log scale). Ranges are for radians read by the
# thesis's encoder; `knob_range` rescales the ones that scale with the step Δ (Kalman q ∝ Δ²,
# FOAW d ∝ Δ) for any other encoder or unit.
KNOBS: dict[str, tuple[str, float, float, bool]] = {
    "filtered_first_difference": ("corner", 10.0, 3000.0, True),  # λ [rad/s]
    "kalman_cv": ("q", 1e-9, 1e2, True),  # white acceleration density [position²/s³]
    "kalman_ca": ("q", 1e-7, 1e9, True),  # white jerk density [position²/s⁵]
    "kalman_model": ("q", 1e-12, 1e2, True),  # white acceleration disturbance [position²/s³]
    "luenberger": ("bandwidth", 10.0, 3000.0, True),  # ω [rad/s]
    "luenberger_model": ("bandwidth", 1.0, 3000.0, True),  # ω [rad/s]
    "levant": ("lipschitz", 0.1, 1e6, True),  # L [position/s²]
    "foaw": ("d", 1e-5, 1e-3, True),  # noise band [position]
}
_STEP_POWER = {"kalman_cv": 2, "kalman_ca": 2, "kalman_model": 2, "foaw": 1}


def knob_range(name: str, step: float = THESIS_STEP) -> tuple[str, float, float, bool] | None:
    """KNOBS[name] for an encoder of step Δ (None for an estimator without a knob)."""
    if name not in KNOBS:
        return None
    knob, low, high, log = KNOBS[name]
    scale = (step / THESIS_STEP) ** _STEP_POWER.get(name, 0)
    return knob, low * scale, high * scale, log


def nominal_model(n_joints: int, structure: str | None = None) -> Model:
    """rigid,viscous,coulomb of the structure (manus2 for 2 joints unless told, axis otherwise)."""
    name = structure or ("manus2" if n_joints == 2 else "axis")
    return Model(structure_named(name, n_joints), NOMINAL_MODEL)


def _build(name: str, dt: float, n_joints: int, step: float, k: dict) -> Estimator:
    r = quantization_variance(step)
    if name in MODEL_BASED:
        structure = k.pop("structure", None)
        model = k.pop("model", None) or nominal_model(n_joints, structure)
        if model.n_joints != n_joints:
            raise ManusError(f"the model {model.spec!r} has {model.n_joints} joint(s), the recording {n_joints}")
        dynamics = ModelDynamics(model, dt, **{x: k.pop(x) for x in ("boundary",) if x in k})
        params = k.pop("params", None)
        if params:
            bad = model.violations({**model.defaults(), **{key: float(v) for key, v in params.items()}})
            if bad:  # a model that breaks physics predicts nothing an estimator can follow
                raise ManusError(f"the model's parameters break physics: {'; '.join(bad)}")
        if name == "kalman_model":
            return ModelKalman(dynamics, dt, r=r, theta0=params, **k)
        return Luenberger(dt, dynamics=dynamics, theta0=params, **k)
    if name == "first_difference":
        return FirstDifference(dt=dt)
    if name == "filtered_first_difference":  # λ as an array: a new value reuses the compiled step
        return FilteredFirstDifference(dt=dt, **{x: jnp.asarray(float(v)) for x, v in k.items()})  # pyright: ignore[reportArgumentType]
    if name in ("kalman_cv", "kalman_ca"):
        return KinematicKalman(dt, 2 if name == "kalman_cv" else 3, r=r, **k)
    if name == "luenberger":
        return Luenberger(dt, **k)
    if name == "levant":
        return Levant(dt, **k)
    return Foaw(dt, **{"d": step, **k})  # the noise band of this encoder: one step


def make(name: str, dt: float = 1e-3, n_joints: int = 2, step: float | None = None, **knobs) -> Estimator:
    """The estimator called `name` (one of `NAMES`) at sample period `dt` [s] for an encoder of
    step `step` (default the thesis's 2π/131072 rad); `knobs` are its keyword settings (e.g.
    corner=, q=, steady=, bandwidth=, lipschitz=, d=, window=, model=, params=, structure=,
    boundary=). `n_joints` matters to the model-based ones only (the others work per joint)."""
    if name not in NAMES:
        raise ManusError(f"unknown estimator {name!r}: the estimators are {', '.join(NAMES)}")
    if not dt > 0:
        raise ManusError(f"sample period dt must be positive, got {dt}")
    step = THESIS_STEP if step is None else float(step)
    if not step > 0:
        raise ManusError(f"encoder step must be positive, got {step}")
    unknown = sorted(set(knobs) - set(SETTINGS[name]))
    if unknown:
        accepted = SETTINGS[name]
        raise ManusError(
            f"estimator {name} has no setting {', '.join(unknown)}"
            + (f" (it takes {', '.join(accepted)})" if accepted else " (it takes none)")
        )
    try:
        return _build(name, float(dt), int(n_joints), step, {k: v for k, v in knobs.items() if v is not None})
    except ValueError as e:
        raise ManusError(f"estimator {name}: {e}") from None
