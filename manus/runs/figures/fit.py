"""Figures of a fitted model: `compare` (in the spirit of MATLAB System Identification's
`compare`: measured against predicted, with the NRMSE fit percentage) and the waterfall of the
error falling as `manus discover` adds effects."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from manus.experiments.freerun import nrmse_fit
from manus.runs.figures.common import envelope, panels, pyplot, save, tidy

ZOOM_S = 2.0  # the zoom on the tracking error: this many seconds in the middle of the recording


def compare_figure(f, run, out: Path, name: str = "compare.png", title: str = "") -> str:
    """One row per joint. Column 1: the measured torque (filtered as identification sees it)
    against the model's prediction. Column 2: measured positions against the free run. Column 3
    (closed loop): the tracking error q − q_ref measured and simulated, over a zoom (the position
    alone follows the reference whatever the model). `run` is a `manus.experiments.freerun.FreeRun`,
    or a string saying why there is none (then the torque alone, the string in the title). Long
    series are drawn as what each pixel column shows (`envelope`)."""
    d = f.data
    n = d.n_joints
    t_rows = d.rec.t[d.rows]
    tau, pred = f.data.tau(f.delay), f.predicted()
    fit_tau = nrmse_fit(tau, pred)
    closed = not isinstance(run, str) and run.q_ref is not None
    how = run if isinstance(run, str) else run.how
    fig, axes = panels(
        n,
        1 if isinstance(run, str) else 3 if closed else 2,
        (6.2, 2.3),
        f"{title or Path(d.rec.path).name}: model {f.model.spec}, rel_error {100 * f.rel_error:.2f} %, "
        f"torque low-passed at {d.cutoff_hz:.0f} Hz\nfree run (JAX simulator, fitted parameters): {how}",
    )
    unit = "N·m" if d.rec.structure_name == "manus2" else "N or N·m"
    for i in range(n):
        ax = axes[i, 0]
        ax.plot(*envelope(t_rows, tau[:, i]), color="k", lw=0.7, label="measured (filtered)")
        ax.plot(*envelope(t_rows, pred[:, i]), color="C1", lw=0.7, alpha=0.85, label="model")
        ax.set_title(f"torque, joint {i + 1}: fit {fit_tau[i]:.1f} %", fontsize=9, loc="left")
        ax.set_ylabel(f"τ{i + 1} [{unit}]")
        if isinstance(run, str):  # the title says why there is no free run
            continue
        ax = axes[i, 1]
        ax.plot(*envelope(run.t, run.q[:, i]), color="k", lw=0.8, label="measured")
        ax.plot(*envelope(run.t, run.q_sim[:, i]), color="C0", lw=0.8, ls="--", label=f"free run ({run.mode})")
        ax.set_title(f"position, joint {i + 1}: fit {run.fit_q[i]:.2f} %", fontsize=9, loc="left")
        ax.set_ylabel(f"q{i + 1}")
        if closed:
            ax = axes[i, 2]
            mid = len(run.t) // 2
            half = int(0.5 * ZOOM_S / d.dt)
            sl = slice(max(0, mid - half), mid + half)
            ax.plot(*envelope(run.t[sl], (run.q - run.q_ref)[sl, i]), color="k", lw=0.8, label="measured")
            ax.plot(*envelope(run.t[sl], (run.q_sim - run.q_ref)[sl, i]), color="C0", lw=0.8, ls="--", label="free run")
            ax.set_title(
                f"tracking error q{i + 1} − q_ref{i + 1} (zoom): fit {run.fit_tracking[i]:.1f} % over the whole run",
                fontsize=9,
                loc="left",
            )
    for ax in axes[-1]:
        ax.set_xlabel("t [s]")
    for ax in axes[:-1].flat:  # a column's panels span the same time: its labels under the last row
        ax.tick_params(labelbottom=False)
    for ax in axes[0]:  # every joint's panels say the same: the legend once, on the first joint's
        if ax.has_data():
            ax.legend(loc="upper right", fontsize=7)
    tidy(axes)
    return save(fig, out, name, tight=False)


def waterfall_figure(discovery, out: Path, name: str = "waterfall.png", title: str = "") -> str:
    """The rel_error after each step as falling bars: the start, then one bar per added effect,
    each bar spanning the error it removed; the final level in green."""
    plt = pyplot()
    labels = [discovery.start.model.spec.replace(",", ",\n")]
    levels = [100 * discovery.start.rel_error]
    for s in discovery.steps:
        labels.append(f"+ {s.spec}")
        levels.append(100 * s.rel_error)
    fig, ax = plt.subplots(figsize=(1.6 * len(levels) + 2.5, 4))
    ax.bar(0, levels[0], color="0.55", width=0.6)
    for k in range(1, len(levels)):
        drop = levels[k - 1] - levels[k]
        ax.bar(k, drop, bottom=levels[k], color="C0" if drop > 0 else "C3", width=0.6)
        ax.plot([k - 1.3, k + 0.3], [levels[k - 1]] * 2, color="0.4", lw=0.7, ls=":")
        ax.text(k, levels[k - 1], f"−{drop:.2f}", ha="center", va="bottom", fontsize=8)
    ax.bar(len(levels), levels[-1], color="C2", width=0.6)
    ax.text(len(levels), levels[-1], f"{levels[-1]:.2f} %", ha="center", va="bottom", fontsize=8)
    ax.text(0, levels[0], f"{levels[0]:.2f} %", ha="center", va="bottom", fontsize=8)
    ax.set_xticks(np.arange(len(levels) + 1), labels + ["final"], fontsize=8)
    ax.set_ylabel("rel_error ‖τ − τ̂‖ / ‖τ‖ [%]")
    ax.set_ylim(0, 1.12 * max(levels))
    fig.suptitle(f"{title}: the error falling as effects are added (stopped: {discovery.stopped})", fontsize=9)
    fig.tight_layout()
    return save(fig, out, name)
