"""Models linear in their parameters: regressors, fitting, diagnosis, adaptation laws, controllers."""

from manus.adaptive.composite import Composite
from manus.adaptive.controllers import NAMES as CONTROLLERS
from manus.adaptive.controllers import make_controller
from manus.adaptive.impedance import Impedance
from manus.adaptive.projection import Projection
from manus.adaptive.regressors import Regressor
from manus.adaptive.slotine_li import SlotineLi, replay, rollout

__all__ = ["CONTROLLERS", "Composite", "Impedance", "Projection", "Regressor", "SlotineLi", "make_controller",
           "replay", "rollout"]
