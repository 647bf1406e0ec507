"""Models linear in their parameters: regressors, fitting, diagnosis, adaptation laws, controllers."""

from adaptive.composite import Composite
from adaptive.controllers import NAMES as CONTROLLERS
from adaptive.controllers import make_controller
from adaptive.impedance import Impedance
from adaptive.projection import Projection
from adaptive.regressors import Regressor
from adaptive.slotine_li import SlotineLi, replay, rollout

__all__ = ["CONTROLLERS", "Composite", "Impedance", "Projection", "Regressor", "SlotineLi", "make_controller",
           "replay", "rollout"]
