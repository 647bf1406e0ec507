"""Errors that reach a user: each says what is wrong in one line, naming the thing at fault."""

from __future__ import annotations

import importlib
from types import ModuleType


class ManusError(Exception):
    """A problem with the user's input or set-up (bad file, unknown effect, dead link, ...).

    The command line prints its message on one line and exits non-zero, without a traceback.
    """


class RecordingError(ManusError):
    """A recording file that breaks the contract of docs/recording.md."""


class ModelError(ManusError):
    """A model that cannot be built or identified (unknown effect, unidentifiable parameter)."""


class RecordingNote(UserWarning):
    """Something done to a recording as it was read that its user should know (a cut last line
    dropped, a wrapped angle unwrapped); the command line prints it as one line."""


def require(module: str, extra: str) -> ModuleType:
    """Import `module`, which only the optional extra `extra` installs; a `ManusError` naming the
    extra when it is missing (e.g. `require("cvxpy", "consistency")`)."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise ManusError(f"this needs {module}, which is not installed: pip install 'manus[{extra}]'") from None
