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
import atexit
import contextlib
import gc
import importlib
import os
import pkgutil
import sys
import threading
from types import ModuleType

from manus import runs
from manus.runs.progress import notes_as_lines, set_quiet
from manus.runs.text import json_text


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
    cmds = commands()  # (numpy and JAX configured when manus was imported: `manus.config`)
    args = parser(cmds).parse_args(argv)
    from manus.plants.errors import ManusError

    module = cmds[args.command]
    set_quiet(args.json and not args.progress)
    try:
        with notes_as_lines(args.command):
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


def entry() -> None:
    """The `manus` executable: `main`, then out of the process once its output is flushed, its
    threads joined and its exit handlers run, as at any exit, but without the interpreter's
    teardown of every object it holds (the arrays, compiled programs and modules freed one by one
    for a process about to end: 0.4 s after a diagnosis of a 7-joint arm). The objects its imports
    made (about 150 000 tracked by the collector) are kept out of the garbage collector's full passes
    (`gc.freeze`), which are made rarer: they went through all of them five times in a diagnosis
    of a 7-joint arm, 0.4 s holding the interpreter (the analysis makes few reference cycles)."""
    gc.freeze()
    gc.set_threshold(10_000, 20, 20)
    code = main()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(BrokenPipeError, ValueError):  # (a reader gone, as in `manus ... | head`)
            stream.flush()
    threading._shutdown()  # type: ignore[attr-defined]  # (what the interpreter's exit does first)
    atexit._run_exitfuncs()
    os._exit(code)


def _version() -> str:
    from manus import __version__

    return __version__


if __name__ == "__main__":
    entry()
