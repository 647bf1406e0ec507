"""manus: adaptive control of interactive robots in JAX.

From Python (a notebook, a script), the commands' analyses: `manus.read`, `manus.fit`,
`manus.diagnose`, `manus.discover`, `manus.estimators` (`manus.runs.api`). The library's layers
are `manus.plants`, `manus.estimators`, `manus.adaptive`, `manus.experiments` and `manus.runs`
(docs/architecture.md). Importing manus sets JAX to float64 (`manus.config`).
"""

import sys
import types
from importlib.metadata import PackageNotFoundError, version
from typing import TYPE_CHECKING

from manus.config import configure as _configure

try:
    __version__ = version("manus")
except PackageNotFoundError:  # a source tree that was never installed
    __version__ = "0+unknown"

_configure()  # float64 and the environment, for the command and a notebook alike

__all__ = ["__version__", "diagnose", "discover", "fit", "read"]  # and the package `estimators`, callable
API = ("read", "fit", "diagnose", "discover")

if TYPE_CHECKING:
    from manus.runs.api import diagnose, discover, fit, read


class _Estimators(types.ModuleType):
    """`manus.estimators`: the package of velocity estimators (`make`, `compiled_step`, ...) and,
    called, the comparison of every estimator on a recording (`manus.runs.api.estimators`)."""

    def __call__(self, source, **options):
        from manus.runs.api import estimators

        return estimators(source, **options)


import manus.estimators  # noqa: E402, F401 (after the configuration: it imports JAX)

sys.modules["manus.estimators"].__class__ = _Estimators  # (a module's class may be a ModuleType subclass)


def __getattr__(name: str):
    """The Python API's functions (`API`), imported from `manus.runs.api` when first asked for."""
    if name in API:
        from manus.runs import api

        return getattr(api, name)
    raise AttributeError(f"module 'manus' has no attribute {name!r}")
