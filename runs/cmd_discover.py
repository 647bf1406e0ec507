"""`manus discover REC --model EFFECTS`: the loop of issue 4 (`manus.adaptive.discover`): diagnose, add
the verdict, refit, until nothing significant is missing. Prints the table of steps and writes a
report (Markdown with its figures) into `--out`."""

from __future__ import annotations

from pathlib import Path

from manus.runs.cmd_diagnose import limits_line, unexplained_line
from manus.runs.cmd_fit import add_model_options, load
from manus.runs.common import add_common, note, table

NAME = "discover"
HELP = "the loop: diagnose, add the missing effect, refit, until nothing significant is missing; writes a report"


def add_arguments(p) -> None:
    add_model_options(p)
    p.add_argument("--max-steps", type=int, default=6, help="stop after this many additions (default 6)")
    p.add_argument("--no-figures", action="store_true", help="skip the figures and the report")
    add_common(p)


def discover_section(rec, model: str, out: Path, prefix: str, title: str, intro: str = "", cutoff_hz=None,
                     max_steps: int = 6, figures: bool = True, method: str = "auto"):
    """Run the loop on `rec` and make its report section (figures drawn into `out`)."""
    from manus.adaptive.discover import discover
    from manus.runs.report import Section, make_figures

    disc = discover(rec, model, cutoff_hz=cutoff_hz, max_steps=max_steps, method=method,
                    progress=lambda line: note("  " + line))
    section = Section(title, str(rec.path), disc, intro=intro)
    if figures:
        note("  figures ...")
        make_figures(section, out, prefix)
    return section


def result(section) -> dict:
    r = section.discovery.report()
    r["recording"] = section.recording
    if section.figures:
        r["figures"] = {"waterfall": section.figures["waterfall"], "compare": section.figures["compare"],
                        "steps": [p for _, p in section.figures["steps"]]}
        if "resid" in section.figures:
            r["figures"]["resid"] = section.figures["resid"]
        r["free_run"] = section.free_run
    return r


def run(args) -> dict:
    from manus.plants.errors import ManusError
    from manus.runs import report

    if args.max_steps < 1:
        raise ManusError(f"--max-steps {args.max_steps}: at least 1")
    rec = load(args, proposing=True)
    stem = Path(rec.path).stem
    note(f"discovering from {args.model} ...")
    sec = discover_section(rec, args.model, args.out, f"discover_{stem}_", f"{Path(rec.path).name} from `{args.model}`",
                           cutoff_hz=args.cutoff, max_steps=args.max_steps, figures=not args.no_figures,
                           method=args.method)
    r = result(sec)
    if not args.no_figures:
        r["report"] = report.write([sec], Path(args.out) / f"discover_{stem}.md", f"manus discover: {Path(rec.path).name}")
    return r


def render(r: dict) -> str:
    from manus.runs.report import format_params, left

    rows = [[0, f"(start) {r['start']['model']}", "", f"{100 * r['start']['rel_error']:.2f}"]]
    rows += [[s["step"], s["spec"], format_params(s["params"]), f"{100 * s['rel_error']:.2f}"] for s in r["steps"]]
    lines = [table(left(rows, (1, 2)), ["step", "effect added", "parameters (value±std)", "rel_error %"]),
             f"stopped: {r['stopped']}; final model {r['model']}, rel_error {100 * r['rel_error']:.2f} %"]
    lines += [f"  step {s['step']}: {s['note']}" for s in r["steps"] if s.get("note")]
    lines += [f"  {n}" for n in r["notes"]]
    lines.append(f"  fitted by {r['method']}: {r['method_why']}")
    if r["stopped"] == "nothing significant missing" and r.get("detection_limits"):
        lines.append("  " + limits_line(r["detection_limits"]))
    lines.append("  " + unexplained_line(r.get("unexplained") or {}))
    if "report" in r:
        lines.append(f"report: {r['report']}")
    return "\n".join(lines)
