"""Figures of a fitted model: `compare` (in the spirit of MATLAB System Identification's
`compare`: measured against predicted, with the NRMSE fit percentage) and the waterfall of the
error falling as `manus discover` adds effects. `draw_*` builds a figure, `*_figure` writes it."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from manus.experiments.freerun import nrmse_fit
from manus.runs.figures.common import PRISMATIC, envelope, labelled, panels, recording_units, save, styled, tidy

if TYPE_CHECKING:
    from matplotlib.figure import Figure

ZOOM_S = 2.0  # the zoom on the tracking error: this many seconds in the middle of the recording


@styled
def draw_compare(f, run, title: str = "") -> Figure:
    """One row per joint. Column 1: the measured torque (filtered as identification sees it)
    against the model's prediction. Column 2: measured positions against the free run. Column 3
    (closed loop): the tracking error q − q_ref measured and simulated, over a zoom (the position
    alone follows the reference whatever the model). `run` is a `manus.experiments.freerun.FreeRun`,
    or a string saying why there is none (then the torque alone, the string in the note under the
    panels). Each joint in its own units (N·m and rad, or N and m on a prismatic joint). Long
    series are drawn as what each pixel column shows (`envelope`)."""
    d = f.data
    n = d.n_joints
    units = recording_units(d.rec)
    t_rows = d.rec.t[d.rows]
    tau, pred = f.data.tau(f.delay), f.predicted()
    fit_tau = nrmse_fit(tau, pred)
    closed = not isinstance(run, str) and run.q_ref is not None
    how = run if isinstance(run, str) else run.how
    fig, axes = panels(
        n,
        1 if isinstance(run, str) else 3 if closed else 2,
        (6.2, 2.3),
        f"{title or Path(d.rec.path).name}: model {f.model.spec}, rel_error {100 * f.rel_error:.2f} %",
        note=f"Torque low-passed at {d.cutoff_hz:.0f} Hz, as identification sees it. "
        f"Free run (the JAX simulator with the fitted parameters): {how}",
    )
    for i in range(n):
        u = units[i]
        what = "force" if u is PRISMATIC else "torque"
        ax = axes[i, 0]
        ax.plot(*envelope(t_rows, tau[:, i]), color="k", lw=0.7, label="measured (filtered)")
        ax.plot(*envelope(t_rows, pred[:, i]), color="C1", lw=0.7, alpha=0.85, label="model")
        ax.set_title(f"{what}, joint {i + 1}: fit {fit_tau[i]:.1f} %", loc="left")
        ax.set_ylabel(labelled(f"τ{i + 1}", u.torque))
        if isinstance(run, str):  # the note says why there is no free run
            continue
        ax = axes[i, 1]
        ax.plot(*envelope(run.t, run.q[:, i]), color="k", lw=0.8, label="measured")
        ax.plot(*envelope(run.t, run.q_sim[:, i]), color="C0", lw=0.8, ls="--", label=f"free run ({run.mode})")
        ax.set_title(f"position, joint {i + 1}: fit {run.fit_q[i]:.2f} %", loc="left")
        ax.set_ylabel(labelled(f"q{i + 1}", u.position))
        if closed:
            ax = axes[i, 2]
            mid = len(run.t) // 2
            half = int(0.5 * ZOOM_S / d.dt)
            sl = slice(max(0, mid - half), mid + half)
            ax.plot(*envelope(run.t[sl], (run.q - run.q_ref)[sl, i]), color="k", lw=0.8, label="measured")
            ax.plot(*envelope(run.t[sl], (run.q_sim - run.q_ref)[sl, i]), color="C0", lw=0.8, ls="--", label="free run")
            ax.set_title(f"tracking error (zoom): fit {run.fit_tracking[i]:.1f} % over the run", loc="left")
            ax.set_ylabel(labelled(f"q{i + 1} − q_ref{i + 1}", u.position))
    for ax in axes.flat:
        ax.set_xlabel("t [s]")
    for ax in axes[0]:  # every joint's panels say the same: the legend once, on the first joint's
        if ax.has_data():
            ax.legend(loc="upper right")
    tidy(axes)
    return fig


def compare_figure(f, run, out: Path, name: str = "compare.png", title: str = "") -> str:
    """`draw_compare` written as `out/name`; returns its path."""
    return save(draw_compare(f, run, title), out, name)


@styled
def draw_waterfall(discovery, title: str = "") -> Figure:
    """The rel_error after each step as falling bars: the start, then one bar per added effect,
    each bar spanning the error it removed; the final level in green. The starting model and why
    the loop stopped in the note under the plot."""
    labels = ["start"]
    levels = [100 * discovery.start.rel_error]
    for s in discovery.steps:
        labels.append(f"+ {s.spec}")
        levels.append(100 * s.rel_error)
    fig, axes = panels(
        1,
        1,
        (max(4.0, 1.25 * (len(levels) + 1)), 3.6),
        f"{title + ': ' if title else ''}the error falling as effects are added",
        note=f"Start: {discovery.start.model.spec}. Final: {discovery.model}. Stopped: {discovery.stopped}.",
    )
    ax = axes[0, 0]
    ax.bar(0, levels[0], color="0.55", width=0.6)
    for k in range(1, len(levels)):
        drop = levels[k - 1] - levels[k]
        ax.bar(k, drop, bottom=levels[k], color="C0" if drop > 0 else "C3", width=0.6)
        ax.plot([k - 1.3, k + 0.3], [levels[k - 1]] * 2, color="0.4", lw=0.7, ls=":")
        ax.text(k, levels[k - 1], f"−{drop:.2f}", ha="center", va="bottom", fontsize=8)
    ax.bar(len(levels), levels[-1], color="C2", width=0.6)
    ax.text(len(levels), levels[-1], f"{levels[-1]:.2f} %", ha="center", va="bottom", fontsize=8)
    ax.text(0, levels[0], f"{levels[0]:.2f} %", ha="center", va="bottom", fontsize=8)
    ax.set_ylabel("rel_error ‖τ − τ̂‖ / ‖τ‖ [%]")
    ax.set_xlabel("model after each step")
    ax.set_ylim(0, 1.12 * max(levels))
    ax.grid(False, axis="x")
    ax.set_xticks(np.arange(len(levels) + 1), labels + ["final"], fontsize=8)
    tidy(axes)
    return fig


def waterfall_figure(discovery, out: Path, name: str = "waterfall.png", title: str = "") -> str:
    """`draw_waterfall` written as `out/name`; returns its path."""
    return save(draw_waterfall(discovery, title), out, name)
