"""What every figure shares: pyplot on the file-only backend, saving into `--out`, and the
figure of a recording (positions, velocities, torques against time)."""

from __future__ import annotations

from pathlib import Path


def figure_dir(out: Path) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend (no screen needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": 110, "axes.grid": True, "grid.alpha": 0.3, "font.size": 9})
    return plt


def save(fig, out: Path, name: str) -> str:
    path = figure_dir(out) / name
    fig.savefig(path, bbox_inches="tight")
    fig.clf()
    import matplotlib.pyplot as plt

    plt.close(fig)
    return str(path)


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
