"""Models linear in their parameters: regressors, identification (`identify`), diagnosis
(`diagnosis`), adaptation laws, controllers."""

from manus.adaptive.composite import Composite
from manus.adaptive.controllers import NAMES as CONTROLLERS
from manus.adaptive.controllers import make_controller
from manus.adaptive.diagnosis.candidates import Candidate
from manus.adaptive.diagnosis.discover import Discovery, Step, discover
from manus.adaptive.diagnosis.verdict import ALPHA, BLOCKS, MIN_SHARE, Diagnosis, diagnose
from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.consistency import Consistency, consistent
from manus.adaptive.identify.fit import METHODS, fit
from manus.adaptive.identify.prepare import Data, prepare
from manus.adaptive.identify.result import Fit
from manus.adaptive.impedance import Impedance
from manus.adaptive.projection import Projection
from manus.adaptive.regressors import Regressor
from manus.adaptive.slotine_li import SlotineLi, replay, rollout

__all__ = [
    "ALPHA",
    "BLOCKS",
    "CONTROLLERS",
    "METHODS",
    "MIN_SHARE",
    "Candidate",
    "Columns",
    "Composite",
    "Consistency",
    "Data",
    "Diagnosis",
    "Discovery",
    "Fit",
    "Impedance",
    "Projection",
    "Regressor",
    "SlotineLi",
    "Step",
    "consistent",
    "diagnose",
    "discover",
    "fit",
    "make_controller",
    "prepare",
    "replay",
    "rollout",
]
