"""The discovery report: a Markdown file with its PNGs beside it, one section per recording
(`manus discover` writes one, `manus demo` two). A section holds the table of steps, the
waterfall of the error falling, each step's evidence figure (the verdict that proposed it), the
residual of the final model and the `compare` figure of the final model."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from manus.runs.common import figure_dir


@dataclass
class Section:
    title: str
    recording: str
    discovery: object  # adaptive.discover.Discovery
    figures: dict = field(default_factory=dict)  # "waterfall", "steps" [(spec, path)], "resid", "compare"
    intro: str = ""
    free_run: str = ""  # one line: what drove the free run (or why there is none)


def step_rows(discovery) -> list[list]:
    """The table of `manus discover`: step, effect added, its parameters, rel_error."""
    rows = [[0, f"(start) {discovery.start.model.spec}", "", f"{100 * discovery.start.rel_error:.2f}"]]
    for s in discovery.steps:
        rows.append([s.index, s.spec, format_params(s.params), f"{100 * s.rel_error:.2f}"])
    return rows


def left(rows: list[list], columns: tuple[int, ...]) -> list[list]:
    """Pad the text of `columns` to a common width, so that `manus.runs.common.table` (which right-aligns
    every column but the first) shows them left-aligned."""
    rows = [list(r) for r in rows]
    for j in columns:
        w = max((len(str(r[j])) for r in rows), default=0)
        for r in rows:
            r[j] = str(r[j]).ljust(w)
    return rows


def format_params(params: dict) -> str:
    parts = []
    for k, v in params.items():
        if isinstance(v, dict):
            std = v.get("std")
            parts.append(f"{k}={v['value']:.4g}" + (f"±{std:.2g}" if std is not None else ""))
        elif isinstance(v, float):
            parts.append(f"{k}={v:.4g}")
        elif k not in ("measured_in",):
            parts.append(f"{k}={v}")
    return ", ".join(parts)


def make_figures(section: Section, out: Path, prefix: str, free_run: bool = True) -> None:
    """Draw the section's figures into `out` (names start with `prefix`)."""
    from manus.runs.cmd_fit import free_run_or_reason
    from manus.runs.diagnose_figures import evidence_figure, resid_figure, unexplained_figure
    from manus.runs.fit_figures import compare_figure, waterfall_figure

    disc = section.discovery
    name = Path(section.recording).name
    figs = {"waterfall": waterfall_figure(disc, out, f"{prefix}waterfall.png", name), "steps": []}
    for s in disc.steps:
        path = evidence_figure(s.diagnosis, s.verdict, out, f"{prefix}step{s.index}_{s.effect}.png", name)
        figs["steps"].append((s.spec, path))
    if disc.final is not None:
        figs["resid"] = resid_figure(disc.final, out, f"{prefix}final_resid.png", name)
        left = unexplained_figure(disc.final, out, f"{prefix}final_unexplained.png", name)
        if left:
            figs["unexplained"] = left
    final = disc.final_fit
    run = free_run_or_reason(final) if free_run else "skipped"
    section.free_run = run if isinstance(run, str) else run.how
    figs["compare"] = compare_figure(final, run, out, f"{prefix}final_compare.png", name)
    section.figures = figs


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
        md += [f"Recording `{sec.recording}`: {disc.start.data.rows.size} rows, torque low-passed at "
               f"{disc.start.data.cutoff_hz:.1f} Hz. Stopped: **{disc.stopped}**. Final model `{disc.model}`, "
               f"rel_error **{100 * disc.rel_error:.2f} %** (from {100 * disc.start.rel_error:.2f} %).", ""]
        md += [_md_table(step_rows(disc), ["step", "effect added", "parameters (value±std)", "rel_error %"]), ""]
        for n in disc.notes:
            md += [f"- {n}"]
        f = sec.figures
        if "waterfall" in f:
            md += ["### The error falling", "", f"![waterfall]({_link(f['waterfall'], base)})", ""]
        for (spec, fig), s in zip(f.get("steps", []), disc.steps):
            v = s.verdict
            md += [f"### Step {s.index}: + `{spec}`", "",
                   f"The diagnosis of `{s.diagnosis.base.model.spec}` proposed it: it removes "
                   f"{100 * v.error_reduction:.1f} % of the error ({100 * v.cv_error_reduction:.1f} % on held-out "
                   f"blocks, p = {v.p_value:.2g}). rel_error {100 * s.rel_error_before:.2f} % → {100 * s.rel_error:.2f} %."
                   + (f" {s.note}." if s.note else ""), "", f"![{spec}]({_link(fig, base)})", ""]
        if "resid" in f:
            md += ["### What is left: the final model's residual", "",
                   "No effect of the vocabulary is significant on held-out blocks any more; the residual analysis in "
                   "the spirit of MATLAB `resid` (99 % bands):", "", f"![resid]({_link(f['resid'], base)})", ""]
        if disc.final is not None and disc.final.verdict is None and disc.final.detection_limits:
            from manus.runs.cmd_diagnose import limits_line

            md += ["### How large a missing effect would have to be", "", limits_line(disc.final.detection_limits) + ".", ""]
        u = disc.unexplained
        if u:
            from manus.runs.cmd_diagnose import unexplained_line

            md += ["### Something left that no effect explains?", "", unexplained_line(u) + ".", ""]
            if "unexplained" in f:
                md += [f"![unexplained]({_link(f['unexplained'], base)})", ""]
        if "compare" in f:
            md += ["### The final model against the measurements", "",
                   f"Measured against predicted torque, and a free run of the fitted model in the JAX simulator "
                   f"({sec.free_run}).", "", f"![compare]({_link(f['compare'], base)})", ""]
    path.write_text("\n".join(md) + "\n")
    return str(path)
