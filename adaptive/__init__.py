"""Models linear in their parameters: regressors, fitting, diagnosis, adaptation laws, controllers."""

from adaptive.impedance import Impedance

__all__ = ["Impedance"]
