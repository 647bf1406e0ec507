"""Figures of chapter 4 and Appendix D: the stability map (Fig. 4-25), the Type 1 curves
(Figs. 4-7, 4-8), a step response on the Type 2 threshold (Figs. 4-22 to 4-24), the maps at
100 Hz (Figs. D-1 to D-3) and the sensitivity of the thresholds. `draw_*` builds a figure, the
other functions write it. The plant is the thesis's linear axis: positions in m, forces in N."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from manus.experiments.stability.steptest import SAMPLES_1KHZ, THESIS_PSD, TYPE1, TYPE2, periodogram
from manus.runs.figures.common import panels, save, spread_scale, styled, tidy

if TYPE_CHECKING:
    from matplotlib.figure import Figure

COLORS = {0: "#d9f0d3", TYPE1: "#9ecae1", TYPE2: "#fdae6b"}  # stable, Type 1, Type 2
# a sensitivity table's parameter: its axis label and the factor from SI to the unit drawn
PARAMETERS = {
    "delay": ("amplifier delay [ms]", 1e3),
    "quantum": ("encoder step [µm]", 1e6),
    "rate_hz": ("control rate [Hz]", 1.0),
}


def _kinds(ax, smap) -> None:
    """The map's verdicts as coloured cells (in the legend), the rows' limits as markers; the
    stiffness axis logarithmic when the grid spans decades."""
    from matplotlib.colors import ListedColormap

    spread_scale(ax, smap.ks, "y")
    cmap = ListedColormap([COLORS[0], COLORS[TYPE1], COLORS[TYPE2]])
    ax.pcolormesh(smap.b_cs, smap.ks, smap.kinds.T, cmap=cmap, vmin=-0.5, vmax=2.5, shading="nearest")
    for kind, marker, label in ((TYPE1, "o", "Type 1 limit"), (TYPE2, "s", "Type 2 limit")):
        rows = smap.limit_kind == kind
        ax.plot(smap.b_cs[rows], smap.limit[rows], marker, ms=3, color="k" if kind == TYPE1 else "C3", label=label)
    ax.set_xlabel("controller damping b_c [N·s/m]")
    ax.set_ylabel("controller stiffness k [N/m]")
    ax.set_ylim(smap.ks[0], smap.ks[-1])
    ax.grid(False)


def _legend(ax, beside) -> None:
    """The legend of the map `ax` on the panel `beside` (its axes off: the legend covers no cell):
    the cells' colours (stable, Type 1, Type 2), then what is drawn over them."""
    from matplotlib.patches import Patch

    handles, labels = ax.get_legend_handles_labels()
    cells = [
        (Patch(color=COLORS[k]), f"{name} (simulated)")
        for k, name in ((0, "stable"), (TYPE1, "Type 1"), (TYPE2, "Type 2"))
    ]
    beside.set_axis_off()
    beside.legend([h for h, _ in cells] + handles, [t for _, t in cells] + labels, loc="upper left", frameon=False)


@styled
def draw_stability_map(smap, curves: dict, title: str = "") -> Figure:
    """Fig. 4-25: stable / Type 1 / Type 2 over (b_c, k), with the linear Type 1 curves."""
    fig, axes = panels(
        1,
        2,
        (4.8, 5.0),
        title or "stability map: 5 mm step, compliant axis, 2.4e-5 m quantizer, 1 ms delay",
        note="Cells: the simulated step test's verdict at each (b_c, k); markers: each b_c's largest stable k "
        "and the kind of instability above it; lines: the linear model's Type 1 threshold.",
        widths=(2.6, 1.0),
    )
    ax = axes[0, 0]
    _kinds(ax, smap)
    b = np.asarray(curves["b_c"])
    ax.plot(b, _nan(curves["continuous"]["0"]), "k-", lw=1.2, label="Type 1, linear eq. 4.1 + 1 ms delay")
    ax.plot(b, _nan(curves["sampled"]), "k--", lw=1, label=f"Type 1, linear, sampled at {curves['rate_hz']:g} Hz")
    ax.plot(b, _nan(curves["sampled_shaft"]), ":", color="C3", lw=1.2, label="linear with the shaft mode, sampled")
    _legend(ax, axes[0, 1])
    ax.set_title("the step test over the grid", loc="left")
    tidy(axes[:, :1])
    return fig


def stability_map(smap, curves: dict, out, name: str = "stability_map.png", title: str = "") -> str:
    """`draw_stability_map` written as `out/name`; returns its path."""
    return save(draw_stability_map(smap, curves, title), out, name)


@styled
def draw_type1_curves(curves: dict) -> Figure:
    """Figs. 4-7 and 4-8: the linear model's largest stable k per b_c, uncoupled and coupled to
    springs (a logarithmic k axis where they span decades)."""
    fig, axes = panels(
        1,
        1,
        (6.0, 4.5),
        "Type 1 threshold: eq. 4.1/4.2 with a 1 ms delay (gain margin)",
    )
    ax = axes[0, 0]
    b = np.asarray(curves["b_c"])
    every = np.concatenate([_nan(ks) for ks in curves["continuous"].values()])
    spread_scale(ax, every[np.isfinite(every)], "y")
    for i, (spring, ks) in enumerate(curves["continuous"].items()):
        label = "uncoupled" if float(spring) == 0 else f"k_env = {float(spring):g} N/m"
        ax.plot(b, _nan(ks), color=f"C{i}", lw=1.4 if float(spring) == 0 else 1, label=label)
    ax.set_xlabel("controller damping b_c [N·s/m]")
    ax.set_ylabel("largest stable k [N/m]")
    ax.set_title("linear model, continuous time", loc="left")
    ax.legend()
    tidy(axes)
    return fig


def type1_curves(curves: dict, out, name: str = "type1_curves.png") -> str:
    """`draw_type1_curves` written as `out/name`; returns its path."""
    return save(draw_type1_curves(curves), out, name)


@styled
def draw_step_response(traj, test, k: float, b_c: float) -> Figure:
    """Figs. 4-22 to 4-24: a step response near the Type 2 threshold, its last 0.2 s, and the
    PSD of its last second against the 10⁻⁶ criterion."""
    fig, axes = panels(
        1,
        3,
        (4.1, 3.4),
        f"step response near the Type 2 threshold: k = {k:.0f} N/m, b_c = {b_c:g} N·s/m",
        note=f"PSD as the thesis computes it, |X|²/N with N = {SAMPLES_1KHZ} samples (m²); shaded: the band "
        f"judged ({test.band[0]:g}–{test.band[1]:g} Hz).",
    )
    a = axes[0]
    t, x = np.asarray(traj.t), np.asarray(traj.q)[:, 0]
    a[0].plot(t, 1e3 * x, lw=0.7)
    a[0].set(xlabel="t [s]", ylabel="x [mm]")
    a[0].set_title("step response", loc="left")
    last = t >= t[-1] - 0.2
    a[1].plot(t[last], 1e3 * x[last], lw=0.7, drawstyle="steps-post")
    a[1].set(xlabel="t [s]", ylabel="x [mm]")
    a[1].set_title("close-up: the last 0.2 s (measured)", loc="left")
    tail = x[-test.tail :]
    f, p = periodogram(tail, test.rate_hz)
    a[2].semilogy(f[1:], np.maximum(np.asarray(p)[1:], 1e-16), lw=0.7)
    a[2].axhline(THESIS_PSD, color="C3", ls="--", lw=0.8, label="1e-6 (Type 2)")
    a[2].axvspan(*test.band, color="C1", alpha=0.1)
    a[2].set(xlabel="frequency [Hz]", ylabel="PSD [m²]")
    a[2].set_title("PSD of the last second", loc="left")
    a[2].legend()
    tidy(axes)
    return fig


def step_response(traj, test, k: float, b_c: float, out, name: str = "type2_response.png") -> str:
    """`draw_step_response` written as `out/name`; returns its path."""
    return save(draw_step_response(traj, test, k, b_c), out, name)


@styled
def draw_appendix_d(maps: dict, summary: dict) -> Figure:
    """Figs. D-1 to D-3: the maps at 100 Hz, uncoupled and against the springs."""
    fig, axes = panels(
        1,
        len(maps) + 1,
        (4.8, 4.0),
        f"stability maps at {summary['rate_hz']:g} Hz (Appendix D)",
        note="Cells: the simulated step test's verdict; markers: each b_c's largest stable k; dashed: the "
        "linear model's Type 1 threshold, sampled.",
        widths=(*[1.0] * len(maps), 0.55),
    )
    for ax, (spring, smap) in zip(axes[0], maps.items(), strict=False):
        _kinds(ax, smap)
        s = summary["springs"][f"{spring:g}"]
        ax.plot(smap.b_cs, _nan(s["linear_sampled"]), "k--", lw=1, label="Type 1, linear, sampled")
        ax.set_title(("uncoupled" if spring == 0 else f"k_env = {spring:g} N/m"), loc="left")
    _legend(axes[0, 0], axes[0, -1])
    tidy(axes[:, :-1])
    return fig


def appendix_d(maps: dict, summary: dict, out, name: str = "appendix_d_100hz.png") -> str:
    """`draw_appendix_d` written as `out/name`; returns its path."""
    return save(draw_appendix_d(maps, summary), out, name)


@styled
def draw_sensitivity(sens: dict) -> Figure:
    """Each probe's limit against each parameter (filled: Type 1, open: Type 2), the parameter in
    its unit (`PARAMETERS`), on a logarithmic axis where its values span decades."""
    tables = sens["tables"]
    fig, axes = panels(
        1,
        len(tables),
        (4.2, 3.6),
        "sensitivity of the thresholds",
        note="Filled markers: the limit is Type 1; open: Type 2. Each probe is one b_c (its largest stable k).",
    )
    for ax, table in zip(axes[0], tables, strict=True):
        label, factor = PARAMETERS.get(table["parameter"], (table["parameter"], 1.0))
        values = [factor * r["value"] for r in table["rows"]]
        spread_scale(ax, values)
        for j, probe in enumerate(table["rows"][0]["probes"]):
            if probe["probe"].startswith("b_c"):
                continue
            lim = [r["probes"][j]["limit"] for r in table["rows"]]
            kinds = [r["probes"][j]["kind"] for r in table["rows"]]
            (line,) = ax.plot(values, lim, "-", lw=0.8, label=probe["probe"])
            for v, k, kd in zip(values, lim, kinds, strict=True):
                ax.plot(v, k, "o", color=line.get_color(), mfc=line.get_color() if kd == "type1" else "none")
        ax.set(xlabel=label, ylabel="largest stable k [N/m]")
        ax.set_title(table["label"], loc="left", fontsize=8)
    axes[0, 0].legend(fontsize=6)
    tidy(axes)
    return fig


def sensitivity(sens: dict, out, name: str = "sensitivity.png") -> str:
    """`draw_sensitivity` written as `out/name`; returns its path."""
    return save(draw_sensitivity(sens), out, name)


def _nan(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], float)
