"""The discovery report: a Markdown file with its PNGs beside it, one section per recording
(`manus discover` writes one, `manus demo` two). A section holds the table of steps, the
waterfall of the error falling, each step's evidence figure (the verdict that proposed it), the
residual of the final model and the `compare` figure of the final model; `discover_section`
runs the loop and draws them."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from manus.plants.files import atomically
from manus.runs.figures.common import figure_dir
from manus.runs.progress import note
from manus.runs.text import STEP_HEADER, limits_line, step_rows, unexplained_line

if TYPE_CHECKING:
    from manus.adaptive import Discovery


@dataclass
class Section:
    title: str
    recording: str
    discovery: Discovery
    figures: dict = field(default_factory=dict)  # "waterfall", "steps" [(spec, path)], "resid", "compare"
    intro: str = ""
    free_run: str = ""  # one line: what drove the free run (or why there is none)


def make_figures(section: Section, out: Path, prefix: str, steps: list) -> None:
    """Draw the section's figures into `out` (names start with `prefix`): the final residual in a
    worker (`Painter`) while the waterfall, the free run and its `compare` figure are made here,
    then the steps' evidence figures (`steps`: their jobs, handed over as the loop added each,
    `step_figure`) the worker has not started."""
    from manus.experiments.freerun import free_run_or_reason
    from manus.runs.figures.diagnose import evidence_panels, resid_figure, resid_panels, unexplained_figure
    from manus.runs.figures.fit import compare_figure, waterfall_figure
    from manus.runs.figures.worker import Painter

    disc = section.discovery
    name = Path(section.recording).name
    n = disc.start.data.n_joints
    painter = Painter(len(disc.steps) * evidence_panels(n) + (resid_panels(n) if disc.final is not None else 0))
    resid = (
        None
        if disc.final is None
        else painter.draw(resid_figure, disc.final.base, out, f"{prefix}final_resid.png", name)
    )
    figs: dict = {"waterfall": waterfall_figure(disc, out, f"{prefix}waterfall.png", name)}
    if disc.final is not None:
        left = unexplained_figure(disc.final, out, f"{prefix}final_unexplained.png", name)
        if left:
            figs["unexplained"] = left
    final = disc.final_fit
    run = free_run_or_reason(final)
    section.free_run = run if isinstance(run, str) else run.how
    figs["compare"] = compare_figure(final, run, out, f"{prefix}final_compare.png", name)
    for _, job in reversed(steps):  # (the last handed over first: the least likely started)
        job.result()
    figs["steps"] = [(spec, job.result()) for spec, job in steps]
    if resid is not None:
        figs["resid"] = resid.result()
    section.figures = figs


def step_figure(painter, step, out: Path, prefix: str, name: str) -> tuple:
    """A step's evidence figure (the candidate it added, beside its diagnosis's verdict) handed to
    `painter`: (its spec, the `Job`)."""
    from manus.runs.figures.diagnose import evidence_figure

    path = f"{prefix}step{step.index}_{step.effect}.png"
    return step.spec, painter.draw(
        evidence_figure, step.diagnosis.base, step.verdict, step.diagnosis.verdict, out, path, name
    )


def discover_section(
    rec,
    model: str,
    out: Path,
    prefix: str,
    title: str,
    intro: str = "",
    cutoff_hz=None,
    max_steps: int = 6,
    figures: bool = True,
    method: str = "auto",
) -> Section:
    """Run the loop on `rec` and make its report section (figures drawn into `out`)."""
    from manus.adaptive import discover
    from manus.runs.figures.diagnose import evidence_panels, resid_panels
    from manus.runs.figures.worker import Painter
    from manus.runs.progress import Bar

    steps: list = []  # each step's evidence figure, handed over as the loop adds the step
    if figures:  # (its figures: at least one step's evidence and the final residual)
        painter = Painter(evidence_panels(rec.n_joints) + resid_panels(rec.n_joints))
        name = Path(str(rec.path)).name

        def drawn(step) -> None:
            steps.append(step_figure(painter, step, out, prefix, name))

    bar = Bar("  candidates judged", "candidate")
    disc = discover(
        rec,
        model,
        cutoff_hz=cutoff_hz,
        max_steps=max_steps,
        method=method,
        progress=lambda line: note("  " + line),
        on_step=drawn if figures else None,
        told=bar,
    )
    section = Section(title, str(rec.path), disc, intro=intro)
    if figures:
        note("  figures ...")
        make_figures(section, out, prefix, steps)
    return section


def section_result(section: Section) -> dict:
    """A section's JSON (`manus discover`'s): the discovery's report, the recording, the figures."""
    r = section.discovery.report()
    r["recording"] = section.recording
    if section.figures:
        r["figures"] = {
            "waterfall": section.figures["waterfall"],
            "compare": section.figures["compare"],
            "steps": [p for _, p in section.figures["steps"]],
        }
        if "resid" in section.figures:
            r["figures"]["resid"] = section.figures["resid"]
        r["free_run"] = section.free_run
    return r


def _md_table(rows: list[list], header: list[str]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _link(path: str, base: Path) -> str:
    return Path(os.path.relpath(path, base)).as_posix()


def write(sections: list[Section], path: Path, title: str = "manus discover") -> str:
    """Write the Markdown report; figure links are relative to it."""
    path = Path(path)
    base = figure_dir(path.parent)
    md = [f"# {title}", ""]
    for sec in sections:
        disc = sec.discovery
        md += [f"## {sec.title}", ""]
        if sec.intro:
            md += [sec.intro, ""]
        md += [
            f"Recording `{sec.recording}`: {disc.start.data.rows.size} rows, torque low-passed at "
            f"{disc.start.data.cutoff_hz:.1f} Hz. Stopped: **{disc.stopped}**. Final model `{disc.model}`, "
            f"rel_error **{100 * disc.rel_error:.2f} %** (from {100 * disc.start.rel_error:.2f} %).",
            "",
        ]
        md += [_md_table(step_rows(disc.report()), STEP_HEADER), ""]
        for n in disc.notes:
            md += [f"- {n}"]
        f = sec.figures
        if "waterfall" in f:
            md += ["### The error falling", "", f"![waterfall]({_link(f['waterfall'], base)})", ""]
        for (spec, fig), s in zip(f.get("steps", []), disc.steps, strict=False):
            v = s.verdict
            md += [
                f"### Step {s.index}: + `{spec}`",
                "",
                f"The diagnosis of `{s.diagnosis.base.model.spec}` proposed it: it removes "
                f"{100 * v.error_reduction:.1f} % of the error ({100 * v.cv_error_reduction:.1f} % on held-out "
                f"blocks, p = {v.p_value:.2g}). rel_error {100 * s.rel_error_before:.2f} % → {100 * s.rel_error:.2f} %."
                + (f" {s.note}." if s.note else ""),
                "",
                f"![{spec}]({_link(fig, base)})",
                "",
            ]
        if "resid" in f:
            md += [
                "### What is left: the final model's residual",
                "",
                "No effect of the vocabulary is significant on held-out blocks any more; the residual analysis in "
                "the spirit of MATLAB `resid` (99 % bands):",
                "",
                f"![resid]({_link(f['resid'], base)})",
                "",
            ]
        if disc.final is not None and disc.final.verdict is None and disc.final.detection_limits:
            md += [
                "### How large a missing effect would have to be",
                "",
                limits_line(disc.final.detection_limits) + ".",
                "",
            ]
        u = disc.unexplained
        if u:
            md += ["### Something left that no effect explains?", "", unexplained_line(u) + ".", ""]
            if "unexplained" in f:
                md += [f"![unexplained]({_link(f['unexplained'], base)})", ""]
        if "compare" in f:
            md += [
                "### The final model against the measurements",
                "",
                f"Measured against predicted torque, and a free run of the fitted model in the JAX simulator "
                f"({sec.free_run}).",
                "",
                f"![compare]({_link(f['compare'], base)})",
                "",
            ]
    with atomically(path) as tmp:
        tmp.write_text("\n".join(md) + "\n")
    return str(path)
