"""Figures of parameter-convergence trials, like thesis Figs. C-2 to C-5."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from manus.runs.figures.common import pyplot, save


def plot_tracking(tr, path: Path, title: str = "") -> str:
    """Tracking errors and commanded torques against time (Figs. C-2, C-4): the first trial,
    and the 10–90 % band over all trials."""
    plt = pyplot()
    n = tr.q_err.shape[-1]
    fig, axes = plt.subplots(2, n, figsize=(5 * n, 5), sharex=True, squeeze=False)
    for i in range(n):
        for row, (x, label) in enumerate(((tr.q_err, f"q{i + 1} − q_d{i + 1} [rad]"), (tr.tau, f"τ{i + 1} [N·m]"))):
            ax = axes[row, i]
            lo, hi = np.percentile(x[:, :, i], [10, 90], axis=0)
            ax.fill_between(tr.t, lo, hi, color="C0", alpha=0.25, lw=0, label="10–90 % of trials")
            ax.plot(tr.t, x[0, :, i], lw=0.7, color="C0", label="trial 1")
            ax.set_ylabel(label)
        axes[0, i].legend(loc="upper right", fontsize=7)
        axes[1, i].set_xlabel("t [s]")
    fig.suptitle(f"tracking errors and command torques — {title}", fontsize=9)
    fig.tight_layout()
    return save(fig, path.parent, path.name)


def plot_estimates(tr, path: Path, title: str = "") -> str:
    """Parameter estimates against time with the truth drawn in (Figs. C-3, C-5), and beside
    them the excitation: the smallest eigenvalue of ∫₀ᵗ YᵀY dt."""
    plt = pyplot()
    P = len(tr.names)
    cols = min(P + 1, 4)
    rows = -(-(P + 1) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.6 * rows), squeeze=False)
    axes = axes.ravel()
    ok = ~tr.stopped
    for i, name in enumerate(tr.names):
        ax, x = axes[i], tr.theta[ok, :, i]
        lo, hi = np.percentile(x, [10, 90], axis=0)
        ax.fill_between(tr.t, lo, hi, color="C0", alpha=0.25, lw=0, label="10–90 %")
        ax.plot(tr.t, x.mean(0), color="C0", lw=1.0, label="mean")
        ax.axhline(tr.truth[i], color="k", ls="--", lw=0.9, label="truth")
        if tr.truth[i]:
            ax.axhspan(0.95 * tr.truth[i], 1.05 * tr.truth[i], color="k", alpha=0.07, lw=0, label="±5 %")
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("t [s]")
    axes[0].legend(fontsize=6, loc="best")
    ax = axes[P]
    lam = tr.lam_min[ok]
    ax.semilogy(tr.t_gram, np.maximum(np.median(lam, 0), 1e-12), color="C3")
    ax.set_title("excitation: λ_min(∫₀ᵗ YᵀY dt)", fontsize=9)
    ax.set_xlabel("t [s]")
    for a in axes[P + 1 :]:
        a.set_visible(False)
    fig.suptitle(f"parameter estimates ({ok.sum()} trials) — {title}", fontsize=9)
    fig.tight_layout()
    return save(fig, path.parent, path.name)
