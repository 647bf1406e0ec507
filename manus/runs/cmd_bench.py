"""`manus bench NAME`: a benchmark of one part, its figures beside a baseline run in the same
process. Each benchmark is a module `runs/bench/<name>.py` with `HELP`, `add_arguments(parser)`,
`run(args) -> {"figures": {...}, ...}` and `render(result) -> str`."""

from __future__ import annotations

import importlib
import pkgutil

from manus.runs.args import add_json

NAME = "bench"
HELP = "benchmarks (sim, estimators, diagnose, converge, stability, hardware, robot, timebase), each beside a baseline"


def benchmarks() -> dict:
    import manus.runs.bench as pkg

    return {m.name: importlib.import_module(f"manus.runs.bench.{m.name}") for m in pkgutil.iter_modules(pkg.__path__)}


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="bench", metavar="NAME", required=True)
    for name, module in sorted(benchmarks().items()):
        sp = sub.add_parser(name, help=module.HELP, description=module.HELP)
        add_json(sp)
        module.add_arguments(sp)


def run(args) -> dict:
    result = benchmarks()[args.bench].run(args)
    result.setdefault("benchmark", args.bench)
    return result


def render(result: dict) -> str:
    return benchmarks()[result["benchmark"]].render(result)
