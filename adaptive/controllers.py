"""The controller registry: one way for the command line and the hardware loop to build a
controller by name.

    make_controller("slotine-li", model, dt=1e-3, estimator="kalman_ca", gamma={"a1": 0.3})

| name | controller | gains (keywords) |
|---|---|---|
| `impedance` | `manus.adaptive.impedance.Impedance`: τ = K (q_d − q) + B (q̇_d − v̂) | stiffness, damping, limit |
| `slotine-li` | `manus.adaptive.slotine_li.SlotineLi`, gradient law | gamma, lam, kd, theta0, form, boundary, project, min_inertia, lead, velocity_lag, limit |
| `slotine-li-composite` | the same with composite adaptation (least-squares gain) | as slotine-li, plus bandwidth, weight, forgetting |

`estimator` is a `manus.estimators.base.Estimator`, a name in `manus.estimators.NAMES` (a model-based one,
`kalman_model` or `luenberger_model`, is built on the controller's model, and Slotine–Li hands it
its current estimates every tick), or None (each controller's default). Every controller
returned is a `manus.plants.stepper.Controller`.
"""

from __future__ import annotations

import numpy as np

from manus import estimators
from manus.adaptive.composite import Composite
from manus.adaptive.impedance import Impedance
from manus.adaptive.slotine_li import SlotineLi
from manus.estimators.base import Estimator
from manus.plants.effects import Model
from manus.plants.errors import ManusError
from manus.plants.stepper import Controller

NAMES = ("impedance", "slotine-li", "slotine-li-composite")
COMPOSITE_KNOBS = ("bandwidth", "weight", "forgetting")


def make_estimator(name: str, dt: float, model: Model, **knobs) -> Estimator:
    """The estimator called `name` (`manus.estimators.NAMES`) for a controller of `model`; a model-based
    one (`*_model`) predicts with that model, and the controller hands it its estimates."""
    if name.endswith("_model"):
        knobs.setdefault("model", model)
    return estimators.make(name, dt, n_joints=model.n_joints, **knobs)


def make_controller(name: str, model: Model, dt: float, estimator: Estimator | str | None = None,
                    **gains) -> Controller:
    """The controller `name` (one of `NAMES`) for `model` at control period `dt` [s]."""
    if name not in NAMES:
        raise ManusError(f"unknown controller {name!r}: expected one of {', '.join(NAMES)}")
    if not isinstance(model, Model):
        raise ManusError(f"make_controller needs a manus.plants.effects.Model, not {type(model).__name__}")
    if isinstance(estimator, str):
        estimator = make_estimator(estimator, dt, model)
    if name == "impedance":
        unknown = sorted(set(gains) - {"stiffness", "damping", "limit"})
        if unknown:
            raise ManusError(f"impedance: unknown gain(s) {', '.join(unknown)} (expected stiffness, damping, limit)")
        if estimator is not None and abs(estimator.dt - dt) > 1e-12:
            raise ManusError(f"the velocity estimator runs at dt = {estimator.dt:g} s but the controller at {dt:g} s")
        for k in ("stiffness", "damping"):
            if k in gains and not np.all(np.isfinite(gains[k]) & (np.asarray(gains[k], float) > 0)):
                raise ManusError(f"impedance: {k} must be positive definite (every entry finite and > 0), "
                                 f"got {gains[k]}")
        return Impedance(n_joints=model.n_joints, estimator=estimator, **gains)
    knobs = {k: gains.pop(k) for k in COMPOSITE_KNOBS if k in gains}
    if knobs and name != "slotine-li-composite":
        raise ManusError(f"{name}: {', '.join(knobs)} belong to slotine-li-composite")
    composite = Composite(**knobs) if name == "slotine-li-composite" else None
    import inspect

    settings = [k for k, p in inspect.signature(SlotineLi).parameters.items() if p.kind is p.KEYWORD_ONLY
                and k != "composite"]
    unknown = sorted(set(gains) - set(settings))
    if unknown:
        raise ManusError(f"{name} has no setting {', '.join(unknown)} (its settings: {', '.join(settings)})")
    return SlotineLi(model, dt, estimator, composite=composite, **gains)
