"""`manus discover REC --model EFFECTS`: the loop of `manus.adaptive.diagnosis.discover`: diagnose, add the
verdict, refit, until nothing significant is missing. Prints the table of steps and writes a
report (Markdown with its figures) into `--out`."""

from __future__ import annotations

from pathlib import Path

from manus.runs.args import add_common, add_model_options, load_recording
from manus.runs.text import discovery_text

NAME = "discover"
HELP = "the loop: diagnose, add the missing effect, refit, until nothing significant is missing; writes a report"


def add_arguments(p) -> None:
    add_model_options(p)
    p.add_argument("--max-steps", type=int, default=6, help="stop after this many additions (default 6)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures and the report")
    add_common(p)


def run(args) -> dict:
    from manus.plants.errors import ManusError
    from manus.runs import report
    from manus.runs.analyses import discover_recording

    if args.max_steps < 1:
        raise ManusError(f"--max-steps {args.max_steps}: at least 1")
    rec = load_recording(args, proposing=True)
    a = discover_recording(
        rec,
        args.model,
        cutoff_hz=args.cutoff,
        method=args.method,
        max_steps=args.max_steps,
        figures=None if args.no_figures else args.out,
    )
    if not args.no_figures:
        stem = Path(rec.path).stem
        a.report["report"] = report.write(
            [a.section], Path(args.out) / f"discover_{stem}.md", f"manus discover: {Path(rec.path).name}"
        )
    return a.report


def render(r: dict) -> str:
    return discovery_text(r)
