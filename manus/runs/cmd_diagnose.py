"""`manus diagnose REC --model EFFECTS`: where does the model fail, and which effect is missing?
(`manus.adaptive.diagnosis`: every effect not in the model is a candidate, judged on held-out blocks.)
Writes the residual figure (`resid`) and one evidence figure per candidate."""

from __future__ import annotations

from pathlib import Path

from manus.runs.args import add_common, add_model_options, load_recording
from manus.runs.text import diagnosis_text

NAME = "diagnose"
HELP = "where the model fails and which physical effect is missing: candidates best first, a verdict, figures"


def add_arguments(p) -> None:
    add_model_options(p)
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_common(p)


def run(args) -> dict:
    from manus.plants.effects import ORDER, Model
    from manus.runs.analyses import diagnose_recording
    from manus.runs.figures.diagnose import (
        diagnosis_figures,
        evidence_panels,
        evidence_there,
        resid_figure,
        resid_panels,
    )
    from manus.runs.figures.worker import Painter

    rec = load_recording(args, proposing=True)
    model = Model(rec.structure, args.model)  # (its spec checked before any work)
    stem = f"diagnose_{Path(rec.path).stem}"
    missing = sum(not model.has(name) for name in ORDER)
    n = rec.n_joints
    painter = None if args.no_figures else Painter(resid_panels(n) + missing * evidence_panels(n))
    resid = []

    def fitted(base) -> None:  # the residual's figure drawn beside the candidates' judging
        if painter is not None:
            resid.append(painter.draw(resid_figure, base, args.out, f"{stem}_resid.png"))

    there = []

    def judged(d) -> None:  # the worker's evidence figures started while what is left is looked at
        if painter is not None:
            there.append(evidence_there(d, args.out, stem, painter))

    a = diagnose_recording(rec, args.model, cutoff_hz=args.cutoff, method=args.method, fitted=fitted, judged=judged)
    out = a.report
    if painter is not None:
        out["figures"] = diagnosis_figures(a.diagnosis, args.out, stem, painter, resid[0], there[0])
    return out


def render(r: dict) -> str:
    return diagnosis_text(r)
