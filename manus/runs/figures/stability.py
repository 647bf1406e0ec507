"""Figures of chapter 4 and Appendix D: the stability map (Fig. 4-25), the Type 1 curves
(Figs. 4-7, 4-8), a step response on the Type 2 threshold (Figs. 4-22 to 4-24), the maps at
100 Hz (Figs. D-1 to D-3) and the sensitivity of the thresholds."""

from __future__ import annotations

import numpy as np

from manus.experiments.stability.steptest import SAMPLES_1KHZ, THESIS_PSD, TYPE1, TYPE2, periodogram
from manus.runs.figures.common import pyplot, save

COLORS = {0: "#d9f0d3", TYPE1: "#9ecae1", TYPE2: "#fdae6b"}  # stable, Type 1, Type 2


def _kinds(ax, smap) -> None:
    """The map's verdicts as coloured cells, the rows' limits as markers."""
    from matplotlib.colors import ListedColormap

    cmap = ListedColormap([COLORS[0], COLORS[TYPE1], COLORS[TYPE2]])
    ax.pcolormesh(smap.b_cs, smap.ks, smap.kinds.T, cmap=cmap, vmin=-0.5, vmax=2.5, shading="nearest")
    for kind, marker, label in ((TYPE1, "o", "Type 1 (simulated)"), (TYPE2, "s", "Type 2 (simulated)")):
        rows = smap.limit_kind == kind
        ax.plot(smap.b_cs[rows], smap.limit[rows], marker, ms=3, color="k" if kind == TYPE1 else "C3", label=label)
    ax.set_xlabel("controller damping b_c [N·s/m]")
    ax.set_ylabel("controller stiffness k [N/m]")
    ax.set_ylim(smap.ks[0], smap.ks[-1])


def stability_map(smap, curves: dict, out, name: str = "stability_map.png", title: str = "") -> str:
    """Fig. 4-25: stable / Type 1 / Type 2 over (b_c, k), with the linear Type 1 curves."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 5))
    _kinds(ax, smap)
    b = np.asarray(curves["b_c"])
    ax.plot(b, _nan(curves["continuous"]["0"]), "k-", lw=1.2, label="Type 1, linear eq. 4.1 + 1 ms delay")
    ax.plot(b, _nan(curves["sampled"]), "k--", lw=1, label=f"Type 1, linear, sampled at {curves['rate_hz']:g} Hz")
    ax.plot(b, _nan(curves["sampled_shaft"]), ":", color="C3", lw=1.2, label="linear with the shaft mode, sampled")
    ax.legend(fontsize=7, loc="upper right")
    ax.set_title(title or "Stability map: 5 mm step, compliant axis, 2.4e-5 m quantizer, 1 ms delay", fontsize=9)
    return save(fig, out, name)


def type1_curves(curves: dict, out, name: str = "type1_curves.png") -> str:
    """Figs. 4-7 and 4-8: the linear model's largest stable k per b_c, uncoupled and coupled."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6, 4.5))
    b = np.asarray(curves["b_c"])
    for i, (spring, ks) in enumerate(curves["continuous"].items()):
        label = "uncoupled" if float(spring) == 0 else f"k_env = {float(spring):g} N/m"
        ax.plot(b, _nan(ks), color=f"C{i}", lw=1.4 if float(spring) == 0 else 1, label=label)
    ax.set_xlabel("controller damping b_c [N·s/m]")
    ax.set_ylabel("largest stable k [N/m]")
    ax.set_title("Type 1 threshold: eq. 4.1/4.2 with a 1 ms delay (gain margin)", fontsize=9)
    ax.legend(fontsize=7)
    return save(fig, out, name)


def step_response(traj, test, k: float, b_c: float, out, name: str = "type2_response.png") -> str:
    """Figs. 4-22 to 4-24: a step response near the Type 2 threshold, its last 0.2 s, and the
    PSD of its last second against the 10⁻⁶ criterion."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.4))
    t, x = np.asarray(traj.t), np.asarray(traj.q)[:, 0]
    axes[0].plot(t, 1e3 * x, lw=0.7)
    axes[0].set(xlabel="t [s]", ylabel="x [mm]", title=f"step response, k = {k:.0f} N/m, b_c = {b_c:g} N·s/m")
    last = t >= t[-1] - 0.2
    axes[1].plot(t[last], 1e3 * x[last], lw=0.7, drawstyle="steps-post")
    axes[1].set(xlabel="t [s]", ylabel="x [mm]", title="close-up: the last 0.2 s (measured)")
    tail = x[-test.tail :]
    f, p = periodogram(tail, test.rate_hz)
    axes[2].semilogy(f[1:], np.maximum(np.asarray(p)[1:], 1e-16), lw=0.7)
    axes[2].axhline(THESIS_PSD, color="C3", ls="--", lw=0.8, label="1e-6 (Type 2)")
    axes[2].axvspan(*test.band, color="C1", alpha=0.1)
    axes[2].set(xlabel="f [Hz]", ylabel=f"PSD [m²] (|X|²/N, N = {SAMPLES_1KHZ})", title="PSD of the last second")
    axes[2].legend(fontsize=7)
    fig.tight_layout()
    return save(fig, out, name)


def appendix_d(maps: dict, summary: dict, out, name: str = "appendix_d_100hz.png") -> str:
    """Figs. D-1 to D-3: the maps at 100 Hz, uncoupled and against the springs."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(maps), figsize=(4.6 * len(maps), 4), squeeze=False)
    for ax, (spring, smap) in zip(axes[0], maps.items(), strict=True):
        _kinds(ax, smap)
        s = summary["springs"][f"{spring:g}"]
        ax.plot(smap.b_cs, _nan(s["linear_sampled"]), "k--", lw=1, label="Type 1, linear, sampled")
        ax.set_title(
            f"{summary['rate_hz']:g} Hz, " + ("uncoupled" if spring == 0 else f"k_env = {spring:g} N/m"), fontsize=9
        )
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return save(fig, out, name)


def sensitivity(sens: dict, out, name: str = "sensitivity.png") -> str:
    """Each probe's limit against each parameter (filled: Type 1, open: Type 2)."""
    plt = pyplot()
    tables = sens["tables"]
    fig, axes = plt.subplots(1, len(tables), figsize=(3.6 * len(tables), 3.6), squeeze=False)
    for ax, table in zip(axes[0], tables, strict=True):
        values = [r["value"] for r in table["rows"]]
        for j, probe in enumerate(table["rows"][0]["probes"]):
            if probe["probe"].startswith("b_c"):
                continue
            lim = [r["probes"][j]["limit"] for r in table["rows"]]
            kinds = [r["probes"][j]["kind"] for r in table["rows"]]
            (line,) = ax.plot(values, lim, "-", lw=0.8, label=probe["probe"])
            for v, k, kd in zip(values, lim, kinds, strict=True):
                ax.plot(v, k, "o", color=line.get_color(), mfc=line.get_color() if kd == "type1" else "none")
        ax.set(xlabel=table["parameter"], ylabel="largest stable k [N/m]")
        ax.set_title(table["label"], fontsize=8)
    axes[0][0].legend(fontsize=6, title="filled: Type 1, open: Type 2", title_fontsize=6)
    fig.tight_layout()
    return save(fig, out, name)


def _nan(values) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in values], float)
