"""What every figure shares: the style every figure is built and saved in, a grid of panels with
fixed margins (a title above, a wrapped note under), the units of a joint's quantities, the scale of
an axis spanning decades, long series reduced to what a pixel column shows, saving into `--out`, and
the figure of a recording (positions, velocities, torques against time).

A figure is a `matplotlib.figure.Figure` made without pyplot and without choosing a backend: a
builder (`draw_*`) returns it, a notebook shows it inline, and the file functions write it with
`save` (an atomic write; the PNG is rendered by matplotlib's Agg canvas whatever the backend)."""

from __future__ import annotations

import functools
import itertools
import re
import textwrap
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, ParamSpec, TypeVar

import numpy as np

from manus.plants.files import atomically

if TYPE_CHECKING:
    from matplotlib.figure import Figure

DPI = 100
STYLE: dict[Any, Any] = {  # (rcParams: keys matplotlib's typing spells as literals)
    "figure.dpi": DPI,
    "savefig.dpi": DPI,
    "axes.grid": True,
    "grid.alpha": 0.3,
    "font.size": 9,
    "axes.titlesize": 9,
    "axes.labelsize": 9,
    "legend.fontsize": 7,
    "axes.titley": 1.0,  # titles at the top (`tidy` moves what could be under them)
    # glyphs drawn without running each font's hinting program: as legible at 100 dpi, and a fifth
    # less time for a figure set of a 7-joint arm (4.5 -> 3.7 CPU s for diagnose's)
    "text.hinting": "no_hinting",
}
MARGIN = {"left": 0.8, "right": 0.25, "bottom": 0.55, "top": 0.4}  # inches around the grid of panels
GAP = (0.85, 0.75)  # inches between panels: (beside: the next panel's tick labels and y label; below: x label, title)
XLABEL_PT = 20.0  # points from an axis to the top of its label: tick, pad and a 9-pt tick label
TITLE_LINE = 0.19  # inches per line of a figure's title (9 pt)
TITLE_PT = 9.0
NOTE_PT = 8.0
NOTE_LINE = 0.17  # inches per line of a figure's note (8 pt)
NOTE_GAP = 0.12  # inches between the lowest x label and the note
TEXT_SIDE = 0.15  # inches kept clear of the figure's edges by a wrapped title or note
DECADES = 1.5  # a search spanning more than this many decades is drawn on a logarithmic axis

P = ParamSpec("P")
R = TypeVar("R")


def styled(fn: Callable[P, R]) -> Callable[P, R]:
    """`fn` run in the figures' style (`STYLE`, a `matplotlib.rc_context`): a builder's figure
    looks the same in a notebook as in a file, and the notebook's own settings are left as they were."""

    @functools.wraps(fn)
    def run(*args: P.args, **kwargs: P.kwargs) -> R:
        import matplotlib

        with matplotlib.rc_context(STYLE):
            return fn(*args, **kwargs)

    return run


# -- units -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Units:
    """The units of one joint's quantities (SI; a revolute joint's angles in radians)."""

    position: str
    velocity: str
    acceleration: str
    torque: str
    torque_rate: str
    inertia: str


REVOLUTE = Units("rad", "rad/s", "rad/s²", "N·m", "N·m/s", "kg·m²")
PRISMATIC = Units("m", "m/s", "m/s²", "N", "N/s", "kg")


def joint_units(prismatic: Sequence[bool], n: int) -> list[Units]:
    """Each of `n` joints' units: prismatic where `prismatic` (per joint, as `Recording.prismatic`
    or `Structure.prismatic` give it) says so, revolute otherwise (a structure that leaves the
    kind to the recording gives ())."""
    kinds = tuple(prismatic)
    return [PRISMATIC if i < len(kinds) and kinds[i] else REVOLUTE for i in range(n)]


def recording_units(rec) -> list[Units]:
    """The units of a recording's joints (`rec.prismatic`)."""
    return joint_units(rec.prismatic, rec.n_joints)


def parameter_unit(name: str, units: Sequence[Units], known: dict[str, str] | None = None) -> str:
    """The unit of parameter `name`: `known`'s (a model's `Model.units`) when it has it, else read
    from the vocabulary's naming (its joint the trailing number): an inertia (a, M, Ia, Jc, I..),
    a mass or first moment of a chain's link (m, mx..), a damping (b, db, bc), a stiffness (k), else
    a torque (Coulomb, Stribeck, offset, gravity, cogging). "" for a name of no known form."""
    if known and name in known:
        return known[name]
    m = re.fullmatch(r"([A-Za-z]+?)(\d*)", name)
    if m is None or not units:
        return ""
    lead, number = m.group(1), m.group(2)
    j = int(number) - 1 if number else 0
    u = units[j] if 0 <= j < len(units) else units[0]
    if lead in ("a", "Jc") or (lead.startswith("I") and lead != "Ia"):
        return "kg·m²"
    table = {
        "M": u.inertia,
        "Ia": u.inertia,
        "m": "kg",
        "mx": "kg·m",
        "my": "kg·m",
        "mz": "kg·m",
        "b": f"{u.torque}·s/{u.position}",
        "db": f"{u.torque}·s/{u.position}",
        "bc": "N·m·s/rad",  # a coupling's terms: on revolute joints
        "Fcc": "N·m",
        "k": f"{u.torque}/{u.position}",
    }
    if lead in table:
        return table[lead]
    if lead in ("Fc", "dFs", "Fs", "off", "gc", "gs", "A", "B"):
        return u.torque
    return ""


def labelled(quantity: str, unit: str) -> str:
    """An axis label: the quantity and its unit in brackets (a dimensionless one without)."""
    return f"{quantity} [{unit}]" if unit else quantity


# -- layout ------------------------------------------------------------------------------------


def wrap(text: str, width_in: float, size_pt: float = TITLE_PT) -> list[str]:
    """`text` in lines no wider than `width_in` inches at `size_pt` (each line of `text` wrapped
    at spaces; widths measured on the font the figure draws with, with 5 % to spare for hinting)."""
    from matplotlib.font_manager import FontProperties
    from matplotlib.textpath import text_to_path

    if not text:
        return []
    prop = FontProperties(size=size_pt)
    room = 0.95 * width_in * 72.0

    def fits(line: str) -> bool:
        return text_to_path.get_text_width_height_descent(line, prop, ismath=False)[0] <= room

    out = []
    for line in text.splitlines():
        columns = max(10, int(width_in * 72.0 / (0.5 * size_pt)))  # an average character: half an em
        parts = textwrap.wrap(line, columns, break_on_hyphens=False) or [""]
        while columns > 10 and not all(fits(p) for p in parts):
            columns = max(10, int(columns * 0.92))
            parts = textwrap.wrap(line, columns, break_on_hyphens=False) or [""]
        out += parts
    return out


def panels(
    nrows: int,
    ncols: int,
    size: tuple[float, float],
    title: str = "",
    reuse: dict | None = None,
    note: str = "",
    widths: Sequence[float] | None = None,
):
    """A figure of `nrows` × `ncols` panels, each `size` (width, height) inches with its share of
    the gaps, margins fixed in inches, room above for `title` and under the panels for `note`
    (both wrapped to the figure's width: no text makes the figure wider than it was made): no
    layout pass is needed to place them. `widths`: the columns' relative widths (equal when None).
    Returns (fig, axes[nrows, ncols]).

    With `reuse` (a dict kept by the caller over several figures), a figure of the same shape made
    before is emptied and given instead: emptying a panel costs far less than making one (its
    ticks are kept)."""
    from matplotlib.figure import Figure

    w, h = size
    width = ncols * w + MARGIN["left"] + MARGIN["right"] - GAP[0]
    lines = wrap(title, width - 2 * TEXT_SIDE, TITLE_PT)
    notes = wrap(note, width - 2 * TEXT_SIDE, NOTE_PT)
    key = (nrows, ncols, size, len(lines), len(notes), tuple(widths) if widths else None)
    if reuse is not None and key in reuse:
        fig, axes, heading, footnote = reuse[key]
        for ax in axes.flat:
            _empty(ax)
        heading.set_text("\n".join(lines))
        footnote.set_text("\n".join(notes))
        return fig, axes
    head = MARGIN["top"] + TITLE_LINE * len(lines)
    foot = MARGIN["bottom"] + (NOTE_GAP + NOTE_LINE * len(notes) if notes else 0.0)
    height = nrows * h + foot + head - GAP[1]
    axes_w = (width - MARGIN["left"] - MARGIN["right"] - (ncols - 1) * GAP[0]) / ncols
    axes_h = (height - foot - head - (nrows - 1) * GAP[1]) / nrows
    grid: dict[str, Any] = {
        "left": MARGIN["left"] / width,
        "right": 1 - MARGIN["right"] / width,
        "bottom": foot / height,
        "top": 1 - head / height,
        "wspace": GAP[0] / axes_w,
        "hspace": GAP[1] / axes_h,
    }
    if widths:
        grid["width_ratios"] = list(widths)
    fig = Figure(figsize=(width, height), dpi=DPI)
    axes = fig.subplots(nrows, ncols, squeeze=False, gridspec_kw=grid)
    heading = fig.text(0.5, 1 - 0.12 / height, "\n".join(lines), ha="center", va="top", fontsize=TITLE_PT)
    footnote = fig.text(
        TEXT_SIDE / width,
        (0.06 + NOTE_LINE * len(notes)) / height,
        "\n".join(notes),
        ha="left",
        va="top",
        fontsize=NOTE_PT,
        color="0.25",
        linespacing=1.25,
    )
    if reuse is not None:
        reuse[key] = (fig, axes, heading, footnote)
    return fig, axes


def _empty(ax) -> None:
    """A panel as `panels` makes it: what was drawn on it, its legend, titles, labels, scales,
    limits and colour cycle gone, its tick labels at the style's size; its ticks kept."""
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
    ax.tick_params(labelsize=STYLE["font.size"])  # (a figure may have set its tick labels' size)
    ax.set_prop_cycle(None)
    ax.relim()
    ax.set_autoscale_on(True)
    ax.set_axis_on()


def close_all(reuse: dict) -> None:
    """Forget the figures `panels` kept in `reuse` (a figure made without pyplot needs no closing:
    it goes when nothing refers to it)."""
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


def spread_scale(ax, values, which: str = "x") -> str:
    """The scale of an axis over `values` (a parameter searched): logarithmic when they are
    positive and span more than `DECADES` decades; when they start at 0 and their positive part
    spans that much, symmetric-logarithmic, linear from 0 to the smallest positive value and
    logarithmic above (0 drawn, and the first millisecond of a 0–100 ms search plainly apart from
    it); else linear. Sets it on `ax` and returns its name."""
    from matplotlib.ticker import FixedLocator, FuncFormatter

    v = np.asarray(values, float)
    v = v[np.isfinite(v)]
    positive = v[v > 0]
    if positive.size < 2 or (v < 0).any() or np.log10(positive.max() / positive.min()) <= DECADES:
        return "linear"
    axis = ax.xaxis if which == "x" else ax.yaxis
    setter = ax.set_xscale if which == "x" else ax.set_yscale
    if (v == 0).any():
        low = float(positive.min())
        setter("symlog", linthresh=low, linscale=0.3)
        decades = 10.0 ** np.arange(np.ceil(np.log10(low)), np.floor(np.log10(positive.max())) + 1)
        decades = decades[decades >= 2 * low]  # (a label at least 0.6 decade from 0's)
        minor = np.outer(decades / 10, (2.0, 5.0)).ravel()
        axis.set_major_locator(FixedLocator([0.0, *decades]))
        axis.set_minor_locator(FixedLocator(minor[(minor > low) & (minor < positive.max())].tolist()))
        axis.set_major_formatter(FuncFormatter(lambda x, _: f"{x:g}"))
        return "symlog"
    setter("log")
    return "log"


def tidy(axes) -> None:
    """Panels made by `panels`, ready to draw: at most 6 labelled ticks along each axis, minor
    ticks at 2 and 5 of each decade of a logarithmic one (each tick is an artist to build, lay out
    and draw; ticks the figure set are kept), the x label a fixed distance under the axis (not
    placed from its tick labels' extents at each draw), a y axis's multiplier or offset at its top
    right, clear of the panel's title, and the first tick of each axis made now, in the figures'
    style (the ticks added when the figure is drawn copy it)."""
    from matplotlib.ticker import FixedLocator, LogLocator, MaxNLocator, NullFormatter
    from matplotlib.transforms import offset_copy

    for ax in np.ravel(axes):
        under = offset_copy(ax.transAxes, fig=ax.get_figure(), y=-XLABEL_PT, units="points")
        ax.xaxis.set_label_coords(0.5, 0.0, transform=under)
        for axis in (ax.xaxis, ax.yaxis):
            scale = axis.get_scale()
            if scale == "log":
                axis.set_major_locator(LogLocator(numticks=6))
                axis.set_minor_locator(LogLocator(subs=(2.0, 5.0), numticks=12))
                axis.set_minor_formatter(NullFormatter())
            elif scale == "linear" and not isinstance(axis.get_major_locator(), FixedLocator):  # (ticks set: kept)
                axis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10]))
            axis.get_major_ticks(1)
            axis.get_minor_ticks(1)
        ax.yaxis.get_offset_text().set(x=1.0, horizontalalignment="right")


def save(fig: Figure, out: Path, name: str, tight: bool = False) -> str:
    """Write `fig` as `out/name` (atomically: a reader never sees half a file) in the figures'
    style, at `DPI`. Figures made by `panels` are laid out in inches and written as made; `tight`
    crops to what is drawn (one more layout pass). PNG at zlib level 1: a third of the time of the
    default level for files a little larger."""
    import matplotlib

    path = figure_dir(out) / name
    with matplotlib.rc_context(STYLE), atomically(path) as tmp:
        fig.savefig(tmp, dpi=DPI, bbox_inches="tight" if tight else None, pil_kwargs={"compress_level": 1})
    return str(path)


def figure_dir(out: Path) -> Path:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return out


# -- the recording -----------------------------------------------------------------------------


@styled
def draw_recording(rec, title: str = "") -> Figure:
    """Positions (with the reference when recorded), velocities (the true ones, a simulation's)
    and torques against time, one column per joint, in each joint's units."""
    n = rec.n_joints
    units = recording_units(rec)
    rows = 3 if rec.qd is not None else 2
    fig, axes = panels(rows, n, (5.0, 2.2), title or Path(rec.path).name)
    for i in range(n):
        u = units[i]
        ax = axes[0, i]
        ax.plot(*envelope(rec.t, rec.q[:, i]), lw=0.8, label="measured")
        if f"qref{i + 1}" in rec.extra:
            ax.plot(*envelope(rec.t, rec.extra[f"qref{i + 1}"]), lw=0.8, ls="--", label="reference")
        ax.set_ylabel(labelled(f"q{i + 1}", u.position))
        ax.set_title(f"joint {i + 1}: position", loc="left")
        if rec.qd is not None:
            axes[1, i].plot(*envelope(rec.t, rec.qd[:, i]), lw=0.8, color="C2")
            axes[1, i].set_ylabel(labelled(f"q̇{i + 1}", u.velocity))
            axes[1, i].set_title(f"joint {i + 1}: velocity (true)", loc="left")
        axes[-1, i].plot(*envelope(rec.t, rec.tau[:, i]), lw=0.6, color="C3")
        axes[-1, i].set_ylabel(labelled(f"τ{i + 1}", u.torque))
        axes[-1, i].set_title(f"joint {i + 1}: commanded {'force' if u is PRISMATIC else 'torque'}", loc="left")
        for ax in axes[:, i]:
            ax.set_xlabel("t [s]")
    axes[0, 0].legend(loc="upper right")
    tidy(axes)
    return fig


def plot_recording(rec, path: Path, title: str = "") -> str:
    """`draw_recording` written as the PNG `path`."""
    path = Path(path)
    return save(draw_recording(rec, title), path.parent, path.name)
