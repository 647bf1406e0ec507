"""What every figure shares: pyplot on the file-only backend, a grid of panels with fixed margins,
long series reduced to what a pixel column shows, saving into `--out`, and the figure of a recording
(positions, velocities, torques against time)."""

from __future__ import annotations

import itertools
import textwrap
from pathlib import Path

import numpy as np

from manus.plants.files import atomically

DPI = 100
MARGIN = {"left": 0.8, "right": 0.25, "bottom": 0.55, "top": 0.4}  # inches around the grid of panels
GAP = (0.85, 0.75)  # inches between panels: (beside: the next panel's tick labels and y label; below: x label, title)
XLABEL_PT = 20.0  # points from an axis to the top of its label: tick, pad and a 9-pt tick label
TITLE_LINE = 0.19  # inches per line of a figure's title (9 pt)
COLUMNS_PER_INCH = 14  # characters of a 9-pt title per inch of figure width


def figure_dir(out: Path) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend (no screen needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"figure.dpi": DPI, "axes.grid": True, "grid.alpha": 0.3, "font.size": 9})
    return plt


def panels(nrows: int, ncols: int, size: tuple[float, float], title: str = "", reuse: dict | None = None):
    """A figure of `nrows` × `ncols` panels, each `size` (width, height) inches with its share of
    the gaps, margins fixed in inches and room above for `title` (wrapped to the figure's width):
    no layout pass is needed to place them. Returns (fig, axes[nrows, ncols]).

    With `reuse` (a dict kept by the caller over several figures), a figure of the same shape made
    before is emptied and given instead: emptying a panel costs far less than making one (its
    ticks are kept). Save such figures with `close=False` and `close_all(reuse)` at the end."""
    plt = pyplot()
    w, h = size
    width = ncols * w + MARGIN["left"] + MARGIN["right"] - GAP[0]
    lines = [part for line in title.splitlines() for part in textwrap.wrap(line, int(width * COLUMNS_PER_INCH)) or [""]]
    key = (nrows, ncols, size, len(lines))
    if reuse is not None and key in reuse:
        fig, axes, heading = reuse[key]
        for ax in axes.flat:
            _empty(ax)
        heading.set_text("\n".join(lines))
        return fig, axes
    head = MARGIN["top"] + TITLE_LINE * len(lines)
    height = nrows * h + MARGIN["bottom"] + head - GAP[1]
    axes_w = (width - MARGIN["left"] - MARGIN["right"] - (ncols - 1) * GAP[0]) / ncols
    axes_h = (height - MARGIN["bottom"] - head - (nrows - 1) * GAP[1]) / nrows
    grid = {
        "left": MARGIN["left"] / width,
        "right": 1 - MARGIN["right"] / width,
        "bottom": MARGIN["bottom"] / height,
        "top": 1 - head / height,
        "wspace": GAP[0] / axes_w,
        "hspace": GAP[1] / axes_h,
    }
    with plt.rc_context({"axes.titley": 1.0}):  # titles at the top (`tidy` moves what could be under them)
        fig, axes = plt.subplots(nrows, ncols, figsize=(width, height), squeeze=False, gridspec_kw=grid)
    heading = fig.text(0.5, 1 - 0.12 / height, "\n".join(lines), ha="center", va="top", fontsize=9)
    if reuse is not None:
        reuse[key] = (fig, axes, heading)
    return fig, axes


def _empty(ax) -> None:
    """A panel as `panels` makes it: what was drawn on it, its legend, titles, labels, scales,
    limits and colour cycle gone; its ticks kept."""
    for container in list(ax.containers):
        container.remove()
    for artist in [*ax.lines, *ax.collections, *ax.patches, *ax.texts, *ax.images]:
        artist.remove()
    if ax.get_legend() is not None:
        ax.get_legend().remove()
    for loc in ("left", "center", "right"):
        ax.set_title("", loc=loc)
    ax.set_xlabel("")
    ax.set_ylabel("")
    ax.set_xscale("linear")
    ax.set_yscale("linear")
    ax.set_prop_cycle(None)
    ax.relim()
    ax.set_autoscale_on(True)
    ax.set_axis_on()


def close_all(reuse: dict) -> None:
    """Close the figures `panels` kept in `reuse`."""
    import matplotlib.pyplot as plt

    for fig, _, _ in reuse.values():
        plt.close(fig)
    reuse.clear()


def envelope(t: np.ndarray, y: np.ndarray, columns: int = 1500) -> tuple[np.ndarray, np.ndarray]:
    """A long series y(t) reduced to what `columns` pixel columns can show: in each column its
    minimum and its maximum, in the order they occur (spikes stay; plain subsampling would lose
    them). A series of fewer than 4 samples per column is returned whole."""
    n = t.size
    if n < 4 * columns:
        return t, y
    edges = np.linspace(0, n, columns + 1).astype(int)
    keep = []
    for a, b in itertools.pairwise(edges):
        i, j = a + int(np.argmin(y[a:b])), a + int(np.argmax(y[a:b]))
        keep += [min(i, j), max(i, j)]
    return t[keep], y[keep]


def tidy(axes) -> None:
    """Panels made by `panels`, ready to draw: at most 6 labelled ticks along each axis, minor
    ticks at 2 and 5 of each decade of a logarithmic one (each tick is an artist to build, lay out
    and draw), the x label a fixed distance under the axis (not placed from its tick labels' extents
    at each draw), and a y axis's multiplier or offset at its top right, clear of the panel's title."""
    from matplotlib.ticker import LogLocator, MaxNLocator, NullFormatter
    from matplotlib.transforms import offset_copy

    for ax in np.ravel(axes):
        under = offset_copy(ax.transAxes, fig=ax.get_figure(), y=-XLABEL_PT, units="points")
        ax.xaxis.set_label_coords(0.5, 0.0, transform=under)
        for axis in (ax.xaxis, ax.yaxis):
            if axis.get_scale() == "log":
                axis.set_major_locator(LogLocator(numticks=6))
                axis.set_minor_locator(LogLocator(subs=(2.0, 5.0), numticks=12))
                axis.set_minor_formatter(NullFormatter())
            else:
                axis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10]))
        ax.yaxis.get_offset_text().set(x=1.0, horizontalalignment="right")


def save(fig, out: Path, name: str, tight: bool = True, close: bool = True) -> str:
    """Write `fig` as `out/name` and close it (unless `close` is false: a figure `panels` reuses);
    `tight` crops to what is drawn (one more layout pass: figures made by `panels` are already laid
    out). PNG at zlib level 1: a third of the time of the default level for files a little larger."""
    path = figure_dir(out) / name
    with atomically(path) as tmp:
        fig.savefig(tmp, bbox_inches="tight" if tight else None, pil_kwargs={"compress_level": 1})
    if close:
        import matplotlib.pyplot as plt

        plt.close(fig)  # (not `clf`: clearing each panel first rebuilds its ticks)
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
    with atomically(path) as tmp:
        fig.savefig(tmp)
    plt.close(fig)
    return str(path)
