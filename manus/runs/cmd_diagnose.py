"""`manus diagnose REC --model EFFECTS`: where does the model fail, and which effect is missing?
(`manus.adaptive.diagnosis`: every effect not in the model is a candidate, judged on held-out blocks.)
Writes the residual figure (`resid`) and one evidence figure per candidate."""

from __future__ import annotations

from pathlib import Path

from manus.runs.args import add_common, add_model_options, load_recording
from manus.runs.text import diagnosis_text, note

NAME = "diagnose"
HELP = "where the model fails and which physical effect is missing: candidates best first, a verdict, figures"


def add_arguments(p) -> None:
    add_model_options(p)
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_common(p)


def run(args) -> dict:
    from manus.adaptive import diagnose
    from manus.runs.figures.diagnose import diagnosis_figures

    rec = load_recording(args, proposing=True)
    note(f"diagnosing {args.model}: fitting it with each missing effect in turn ...")
    d = diagnose(rec, args.model, cutoff_hz=args.cutoff, method=args.method)
    out = d.report()
    if rec.time_base:  # repeated rows, jittered stamps or a resampled rate found and repaired as it was read
        out["time_base"] = rec.time_base.report()
    if not args.no_figures:
        stem = f"diagnose_{Path(rec.path).stem}"
        out["figures"] = diagnosis_figures(d, args.out, stem)
    return out


def render(r: dict) -> str:
    return diagnosis_text(r)
