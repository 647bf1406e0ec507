"""Velocity (and acceleration) estimators: causal steppers and offline differentiators.

`NAMES` lists them in report order, `make(name, ...)` builds one, `KNOBS[name]` is the knob
`manus estimators --tune` searches. Each is a stepper (`init(q0)`, `step(state, q, tau)`), run over
a recorded array with `run`, or tick by tick with `compiled_step(estimator)`.
"""

from manus.estimators.base import Estimate, Estimator, FilteredFirstDifference, FirstDifference, compiled_step, run
from manus.estimators.registry import KNOBS, MODEL_BASED, NAMES, SETTINGS, knob_range, make

__all__ = [
    "Estimate",
    "Estimator",
    "FilteredFirstDifference",
    "FirstDifference",
    "compiled_step",
    "run",
    "KNOBS",
    "MODEL_BASED",
    "NAMES",
    "SETTINGS",
    "knob_range",
    "make",
]
