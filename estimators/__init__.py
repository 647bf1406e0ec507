"""Velocity (and acceleration) estimators: causal steppers and offline differentiators."""

from estimators.base import Estimate, Estimator, FilteredFirstDifference, FirstDifference, run

__all__ = ["Estimate", "Estimator", "FilteredFirstDifference", "FirstDifference", "run"]
