"""Figures of recordings and trajectories."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from manus.runs.common import pyplot


def plot_recording(rec, path: Path, title: str = "") -> str:
    """Positions (with the reference when recorded), velocities and torques against time."""
    plt = pyplot()
    n = rec.n_joints
    rows = 3 if rec.qd is not None else 2
    fig, axes = plt.subplots(rows, n, figsize=(5 * n, 2.2 * rows), sharex=True, squeeze=False)
    for i in range(n):
        ax = axes[0, i]
        ax.plot(rec.t, rec.q[:, i], lw=0.8, label="measured")
        if f"qref{i + 1}" in rec.extra:
            ax.plot(rec.t, rec.extra[f"qref{i + 1}"], lw=0.8, ls="--", label="reference")
        ax.set_ylabel(f"q{i + 1}")
        ax.legend(loc="upper right", fontsize=7)
        if rec.qd is not None:
            axes[1, i].plot(rec.t, rec.qd[:, i], lw=0.8, color="C2")
            axes[1, i].set_ylabel(f"qd{i + 1} (true)")
        axes[-1, i].plot(rec.t, rec.tau[:, i], lw=0.6, color="C3")
        axes[-1, i].set_ylabel(f"tau{i + 1}")
        axes[-1, i].set_xlabel("t [s]")
    fig.suptitle(title or Path(rec.path).name, fontsize=9)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return str(path)


def rms(x, axis=0):
    return np.sqrt(np.mean(np.square(x), axis=axis))
