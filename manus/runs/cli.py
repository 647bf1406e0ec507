"""The `manus` command. Each sub-command is a module `runs/cmd_<name>.py` with

    NAME = "fit"                     # the sub-command
    HELP = "one line"
    def add_arguments(parser): ...
    def run(args) -> dict            # the result; `--json` prints it, else `render(result)`
    def render(result) -> str        # the human-readable report

Contract (docs/cli.md): `--json` prints one JSON object on stdout and nothing else there;
progress and notes go to stderr; figures go to `--out DIR` (default runs/out/); an error is one
line on stderr and a non-zero exit code.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import json
import math
import os
import pkgutil
import sys
import warnings
from types import ModuleType

from manus import runs

# Measured on this CPU (docs/performance.md): compile a whole scan body as one
# function, and expose both cores as devices for sharded batches.
XLA_FLAGS = (
    "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=1000000000",
    "--xla_force_host_platform_device_count=2",
)


def configure_environment() -> None:
    """The environment numpy and JAX read when they start: numpy's small batched solves on one
    BLAS thread (on a busy 2-core machine OpenBLAS's threads spin-wait far longer than these
    products take), `XLA_FLAGS` (kept where already given), and TensorFlow's logging quiet.
    Call it before numpy or JAX is first imported."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    flags = os.environ.get("XLA_FLAGS", "")
    extra = [f for f in XLA_FLAGS if f.split("=")[0] not in flags]
    os.environ["XLA_FLAGS"] = " ".join([flags, *extra]).strip()
    os.environ.setdefault("TF_CPP_MIN_LOG_LEVEL", "2")


def configure_jax() -> None:
    """The environment (`configure_environment`) and JAX in float64, as `manus` runs: for a
    process the `manus` command did not start (a spawned worker)."""
    configure_environment()
    import jax

    jax.config.update("jax_enable_x64", True)
    _compilation_cache(jax)


CACHE_MIN_COMPILE_S = 0.1  # compilations shorter than this are not worth a file


def _compilation_cache(jax) -> None:
    """JAX's persistent compilation cache in `MANUS_JAX_CACHE` (default `$XDG_CACHE_HOME/manus/jax`,
    else `~/.cache/manus/jax`; `0` or `off`: none), so that a new process finds what an earlier
    one compiled. JAX keys each entry by the computation, its compile options, the XLA flags, the
    device and JAX's version: a hit is the same executable. An entry it cannot read (cut short by
    a concurrent writer) is a warning and a compilation, never a wrong result. A folder that
    cannot be made leaves the cache off."""
    from pathlib import Path

    where = os.environ.get("MANUS_JAX_CACHE", "")
    if where.lower() in ("0", "off"):
        return
    path = Path(where or os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / ("" if where else "manus/jax")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", CACHE_MIN_COMPILE_S)


def commands() -> dict[str, ModuleType]:
    """The sub-commands by name: every module `cmd_*` of this package."""
    found = {}
    for info in pkgutil.iter_modules(runs.__path__):
        if info.name.startswith("cmd_"):
            module = importlib.import_module(f"manus.runs.{info.name}")
            found[module.NAME] = module
    return dict(sorted(found.items()))


def parser(cmds: dict) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="manus",
        description="Adaptive control of interactive robots: "
        "simulate, estimate velocity, fit and diagnose models, adapt, run hardware.",
    )
    p.add_argument("--debug", action="store_true", help="show the full traceback of an error")
    p.add_argument("--version", action="version", version=f"manus {_version()}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, module in cmds.items():
        sp = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(sp)
    return p


def main(argv: list[str] | None = None) -> int:
    configure_environment()  # before a command module imports numpy or JAX
    cmds = commands()
    args = parser(cmds).parse_args(argv)
    configure_jax()
    from manus.plants.errors import ManusError

    module = cmds[args.command]
    try:
        with _notes_as_lines(args.command):
            result = module.run(args)
        text = None if args.json else module.render(result)
    except ManusError as e:
        if args.debug:
            raise
        print(f"manus {args.command}: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"manus {args.command}: interrupted", file=sys.stderr)
        return 130
    except OSError as e:  # the system refused a file (a path that cannot be made, a full disk, permissions)
        if args.debug:
            raise
        where = f": {e.filename}" if e.filename else ""
        print(f"manus {args.command}: {e.strerror or e}{where}", file=sys.stderr)
        return 2
    except Exception as e:  # an unexpected failure: still one line, the traceback on request
        if args.debug:
            raise
        print(
            f"manus {args.command}: internal error: {type(e).__name__}: {e} (run with --debug for the traceback)",
            file=sys.stderr,
        )
        return 1
    if args.json:
        print(json_text(result))
    elif text:
        print(text)
    return 0


def json_text(result: dict) -> str:
    """`result` as strict JSON: numpy values as numbers and lists, and a number that is not finite
    (NaN, ±inf: no JSON number) as null."""

    def finite(x):
        if isinstance(x, float):
            return x if math.isfinite(x) else None
        if isinstance(x, dict):
            return {k: finite(v) for k, v in x.items()}
        if isinstance(x, list):
            return [finite(v) for v in x]
        return x

    return json.dumps(finite(json.loads(json.dumps(result, default=_jsonable))), allow_nan=False)


@contextlib.contextmanager
def _notes_as_lines(command: str):
    """What was done to a recording as it was read (`RecordingNote`: a cut last line dropped, an
    angle unwrapped) printed as one line; any other warning as Python shows it."""
    from manus.plants.errors import RecordingNote

    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message, category, *rest, **kw):
            if issubclass(category, RecordingNote):
                print(f"manus {command}: note: {message}", file=sys.stderr)
            else:
                shown(message, category, *rest, **kw)

        warnings.showwarning = show
        yield


def _version() -> str:
    from manus import __version__

    return __version__


def _jsonable(x):
    import numpy as np

    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serializable: {type(x).__name__}")


if __name__ == "__main__":
    sys.exit(main())
