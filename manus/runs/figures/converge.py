"""Figures of parameter-convergence trials, like thesis Figs. C-2 to C-5. `draw_*` builds a figure,
`plot_*` writes it."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from manus.runs.figures.common import (
    PRISMATIC,
    joint_units,
    labelled,
    panels,
    parameter_unit,
    save,
    styled,
    tidy,
)

if TYPE_CHECKING:
    from matplotlib.figure import Figure


@styled
def draw_tracking(tr, title: str = "", prismatic: Sequence[bool] = ()) -> Figure:
    """Tracking errors and commanded torques against time (Figs. C-2, C-4): the first trial,
    and the 10–90 % band over all trials. `tr`: `manus.experiments.convergence.Trials`;
    `prismatic`: per joint (the plant's `Structure.prismatic`; revolute where it says nothing)."""
    n = tr.q_err.shape[-1]
    units = joint_units(prismatic, n)
    fig, axes = panels(
        2, n, (5.0, 2.5), f"tracking errors and commands: {title}" if title else "tracking errors and commands"
    )
    for i in range(n):
        u = units[i]
        for row, (x, label, what) in enumerate(
            (
                (tr.q_err, labelled(f"q{i + 1} − q_d{i + 1}", u.position), "tracking error"),
                (tr.tau, labelled(f"τ{i + 1}", u.torque), "force" if u is PRISMATIC else "torque"),
            )
        ):
            ax = axes[row, i]
            lo, hi = np.percentile(x[:, :, i], [10, 90], axis=0)
            ax.fill_between(tr.t, lo, hi, color="C0", alpha=0.25, lw=0, label="10–90 % of trials")
            ax.plot(tr.t, x[0, :, i], lw=0.7, color="C0", label="trial 1")
            ax.set_ylabel(label)
            ax.set_xlabel("t [s]")
            ax.set_title(f"joint {i + 1}: {what}", loc="left")
    axes[0, 0].legend(loc="upper right")
    tidy(axes)
    return fig


def plot_tracking(tr, path: Path, title: str = "", prismatic: Sequence[bool] = ()) -> str:
    """`draw_tracking` written as the PNG `path`; returns its path."""
    path = Path(path)
    return save(draw_tracking(tr, title, prismatic), path.parent, path.name)


@styled
def draw_parameters(tr, title: str = "", prismatic: Sequence[bool] = (), units: dict[str, str] | None = None) -> Figure:
    """Parameter estimates against time with the truth drawn in (Figs. C-3, C-5), and beside
    them the excitation: the smallest eigenvalue of ∫₀ᵗ YᵀY dt (on a logarithmic axis). Each
    parameter in its unit: `units` (a model's `Model.units`) where given, else read from its name
    and its joint's kind (`prismatic`; `common.parameter_unit`)."""
    P = len(tr.names)
    n = tr.q_err.shape[-1]
    kinds = joint_units(prismatic, n)
    cols = min(P + 1, 4)
    rows = -(-(P + 1) // cols)
    ok = ~tr.stopped
    fig, grid = panels(
        rows,
        cols,
        (3.8, 2.7),
        f"parameter estimates ({int(ok.sum())} trials): {title}"
        if title
        else f"parameter estimates ({int(ok.sum())} trials)",
        note="Shaded: 10–90 % of the trials; dashed: the truth, ±5 % about it in grey. Last panel: how well the "
        "trajectory excites the parameters, the smallest eigenvalue of ∫₀ᵗ YᵀY dt (its unit mixes the "
        "parameters'), the median over the trials.",
    )
    axes = grid.ravel()
    for i, name in enumerate(tr.names):
        ax, x = axes[i], tr.theta[ok, :, i]
        lo, hi = np.percentile(x, [10, 90], axis=0)
        ax.fill_between(tr.t, lo, hi, color="C0", alpha=0.25, lw=0, label="10–90 %")
        ax.plot(tr.t, x.mean(0), color="C0", lw=1.0, label="mean")
        ax.axhline(tr.truth[i], color="k", ls="--", lw=0.9, label="truth")
        if tr.truth[i]:
            ax.axhspan(0.95 * tr.truth[i], 1.05 * tr.truth[i], color="k", alpha=0.07, lw=0, label="±5 %")
        ax.set_title(name, loc="left")
        ax.set_xlabel("t [s]")
        unit = parameter_unit(name, kinds, units)
        ax.set_ylabel(labelled(name, unit) if unit else f"{name} (SI)")
    axes[0].legend(loc="best")
    ax = axes[P]
    lam = np.maximum(np.median(tr.lam_min[ok], 0), 1e-12)
    ax.plot(tr.t_gram, lam, color="C3")
    ax.set_yscale("log")
    ax.set_title("excitation", loc="left")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("λ_min(∫₀ᵗ YᵀY dt) (SI)")
    for a in axes[P + 1 :]:
        a.set_visible(False)
    tidy(axes[: P + 1])
    return fig


def plot_estimates(
    tr, path: Path, title: str = "", prismatic: Sequence[bool] = (), units: dict[str, str] | None = None
) -> str:
    """`draw_parameters` written as the PNG `path`; returns its path."""
    path = Path(path)
    return save(draw_parameters(tr, title, prismatic, units), path.parent, path.name)
