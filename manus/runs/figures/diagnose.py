"""Figures of a diagnosis: the residual analysis (in the spirit of MATLAB's `resid`) and one
evidence figure per candidate effect, drawn so that a person sees why it is (or is not) missing.
`draw_*` builds a figure, `*_figure` writes it.

The residual is the identification residual of the current model on the used rows (filtered,
decimated: one row every `k` samples; see `manus.adaptive.identify.prepare`). Lags are in
milliseconds; every quantity is in its joint's units (N·m, rad; N, m on a prismatic joint).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from manus.adaptive.diagnosis.leftover import RIPPLE, UNEXPLAINED_MIN, what_removes
from manus.runs.figures.common import (
    PRISMATIC,
    Units,
    close_all,
    envelope,
    labelled,
    panels,
    recording_units,
    save,
    spread_scale,
    styled,
    tidy,
)
from manus.runs.figures.worker import Job, Painter

if TYPE_CHECKING:
    from matplotlib.figure import Figure

Z99 = 2.576  # two-sided 99 % normal quantile
MAX_LAG_ROWS = 60
BINS = 41
WRAP = 4  # panels per row of an evidence figure
BAR_PT = 260.0  # points of axis width a correlogram's bars share (a bar is 0.8 of its lag's width)


def _xcorr(a: np.ndarray, b: np.ndarray, lags: int) -> np.ndarray:
    """Normalized cross-correlation r_ab(k) = Σ a(t+k) b(t) / (N σa σb), k = −lags..lags."""
    a, b = a - a.mean(), b - b.mean()
    N = a.size
    den = N * a.std() * b.std() or 1.0
    return np.array(
        [np.sum(a[max(k, 0) : N + min(k, 0)] * b[max(-k, 0) : N - max(k, 0)]) / den for k in range(-lags, lags + 1)]
    )


def _binned(x: np.ndarray, y: np.ndarray, bins: int = BINS, edges=None):
    """Mean of y and its standard error in bins of x (bins with fewer than 5 points dropped)."""
    if edges is None:
        lo, hi = np.percentile(x, [0.5, 99.5])
        edges = np.linspace(lo, hi, bins + 1)
    k = np.digitize(x, edges) - 1
    centre, mean, se = [], [], []
    for j in range(len(edges) - 1):
        yy = y[k == j]
        if yy.size >= 5:
            centre.append(0.5 * (edges[j] + edges[j + 1]))
            mean.append(yy.mean())
            se.append(yy.std(ddof=1) / np.sqrt(yy.size))
    return np.array(centre), np.array(mean), np.array(se)


def _row_dt(data) -> float:
    return float(np.median(np.diff(data.rows))) * data.dt


def resid_panels(n_joints: int) -> int:
    """The panels of `resid_figure` on `n_joints` joints."""
    return 6 * n_joints


def _outside(r: np.ndarray, band: float) -> str:
    """What a correlogram's title says of its curve against its 99 % band: within it at every lag,
    or at how many lags it leaves it."""
    k = int(np.sum(np.abs(r) > band))
    return "within its 99 % band" if k == 0 else f"{k} of {r.size} lags outside 99 %"


@styled
def draw_resid(f, title: str = "") -> Figure:
    """The residual of fit `f`, per joint two rows of three panels: residual autocorrelation and
    its cross-correlation with the input (the velocity, what drives the inverse model), both with
    99 % bands and titles saying at how many lags each curve leaves its band; the residual against
    time, against velocity, against position (binned means over the cloud); and its spectrum beside
    the torque's. The note under the panels says what the bands are and what the diagnosis's verdict
    on structure left in the residual rests on (held-out fits, not these bands)."""
    from scipy import signal

    data = f.data
    n = data.n_joints
    units = recording_units(data.rec)
    r, rows = f.residual, data.rows
    q, qd, tau = data.q[rows], data.qd[rows], data.tau(f.delay)
    t = data.rec.t[rows]
    h = _row_dt(data)
    L = min(MAX_LAG_ROWS, rows.size // 4)
    lag_ms = np.arange(-L, L + 1) * h * 1e3
    fig, axes = panels(
        2 * n,
        3,
        (4.75, 2.6),
        f"{title or Path(data.rec.path).name}: residual of {f.model.spec}, rel_error {100 * f.rel_error:.2f} %",
        note=f"{rows.size} rows, one per {h * 1e3:.3g} ms (filtered and decimated as identification uses them). "
        "99 % bands: the autocorrelation's for a white residual (±2.58/√N); the cross-correlation's for a "
        "residual independent of the velocity, both autocorrelated (Bartlett); a white residual leaves its band "
        "at about 1 lag in 100. Whether what is left is a missing effect is judged on held-out blocks (the "
        "candidates and 'unexplained' of manus diagnose), not on these bands.",
    )
    for i in range(n):
        u = units[i]
        e = r[:, i]
        acf = _xcorr(e, e, L)
        ccf = _xcorr(e, qd[:, i], L)
        N = e.size
        ax = axes[2 * i, 0]
        white = Z99 / np.sqrt(N)
        ax.vlines(lag_ms[L:], 0, acf[L:], color="C0", lw=_bar_pt(L + 1))
        ax.axhspan(-white, white, color="C3", alpha=0.15, lw=0, label="99 % band (white)")
        ax.set_title(f"joint {i + 1} autocorrelation: {_outside(acf[L + 1 :], white)}", loc="left")
        ax.set_xlabel("lag [ms]")
        ax.set_ylabel(f"r_ee, joint {i + 1}")
        ax = axes[2 * i, 1]
        # the band under 'e independent of the input', for autocorrelated e and u (Bartlett)
        band = Z99 * np.sqrt(max(np.sum(acf * _xcorr(qd[:, i], qd[:, i], L)), 1.0) / N)
        ax.vlines(lag_ms, 0, ccf, color="C2", lw=_bar_pt(2 * L + 1))
        ax.axhspan(-band, band, color="C3", alpha=0.15, lw=0, label="99 % band (independent)")
        ax.set_title(f"residual × q̇{i + 1}: {_outside(ccf, band)}", loc="left")
        ax.set_xlabel("lag [ms] (the velocity leads →)")
        ax.set_ylabel(f"r_eq̇, joint {i + 1}")
        ax = axes[2 * i, 2]
        ax.plot(*envelope(t, e), color="C3", lw=0.6, label="residual")
        mean, sd = float(np.mean(e)), float(np.std(e))
        ax.axhspan(mean - 2 * sd, mean + 2 * sd, color="0.85", lw=0, label="mean ± 2 SD", zorder=0)
        ax.set_title(
            f"residual: RMS {np.sqrt(np.mean(e**2)):.3g} {u.torque}, "
            f"{100 * np.linalg.norm(e) / np.linalg.norm(tau[:, i]):.1f} % of τ{i + 1}",
            loc="left",
        )
        ax.set_xlabel("t [s]")
        ax.set_ylabel(labelled(f"residual {i + 1}", u.torque))
        for ax, x, label in (
            (axes[2 * i + 1, 0], qd[:, i], labelled(f"q̇{i + 1}", u.velocity)),
            (axes[2 * i + 1, 1], q[:, i], labelled(f"q{i + 1}", u.position)),
        ):
            ax.plot(x, e, ".", ms=1.5, color="0.6", alpha=0.5, rasterized=True)
            c, m, se = _binned(x, e)
            ax.errorbar(c, m, yerr=2 * se, color="C3", lw=1.0, capsize=0, label="binned mean ± 2 se")
            ax.axhline(0, color="k", lw=0.6)
            ax.set_xlabel(label)
            ax.set_ylabel(labelled(f"residual {i + 1}", u.torque))
            ax.set_title(f"residual against {label.split(' ')[0]}", loc="left")
        ax = axes[2 * i + 1, 2]
        nper = min(256, e.size)
        fr, pe = signal.welch(e, fs=1 / h, nperseg=nper)
        _, pt = signal.welch(tau[:, i], fs=1 / h, nperseg=nper)
        ax.semilogy(fr, pt, color="0.6", lw=0.8, label="torque" if u is not PRISMATIC else "force")
        ax.semilogy(fr, pe, color="C3", lw=0.9, label="residual")
        k = int(np.argmax(pe[1:])) + 1
        ax.plot(fr[k], pe[k], "v", color="k", ms=5, label="residual's peak")
        ax.axvline(data.cutoff_hz, color="0.4", ls=":", lw=0.8)
        ax.set_xlabel("frequency [Hz] (dotted: identification cut-off)")
        ax.set_ylabel(f"PSD [({u.torque})²/Hz]" if "·" in u.torque else f"PSD [{u.torque}²/Hz]")
        ax.set_title(f"spectrum: residual's peak at {fr[k]:.2f} Hz", loc="left")
    for ax in axes[:2].flat:  # every joint's panels say the same: the legend once, on the first joint's
        ax.legend(loc="upper right")
    tidy(axes)
    return fig


def resid_figure(f, out: Path, name: str = "resid.png", title: str = "") -> str:
    """`draw_resid` written as `out/name`; returns its path."""
    return save(draw_resid(f, title), out, name)


def _bar_pt(bars: int) -> float:
    """The line width (points) of one of `bars` correlogram bars across a panel."""
    return max(0.6, 0.8 * BAR_PT / bars)


# -- evidence per candidate -----------------------------------------------------------------


def _term(c, data) -> np.ndarray:
    """The candidate's fitted torque (its own effect and what it brought) on the used rows,
    unfiltered, (rows, n): drawn over the residual it should explain."""
    import jax
    import jax.numpy as jnp

    from manus.plants.effects import Model

    m = c.fit.model
    own = [m.get(c.effect)] + [m.get(b) for b in m.get(c.effect).brings if m.has(b)]
    model = Model(m.structure, tuple(e for e in own if e is not None and e.linear))
    p = {k: jnp.asarray(v) for k, v in c.fit.params.items() if k in model.names}
    rows = data.rows
    args = (jnp.asarray(data.q[rows]), jnp.asarray(data.qd[rows]), jnp.asarray(data.qdd[rows]))
    return np.asarray(jax.jit(jax.vmap(lambda q, qd, qdd: model.torque(q, qd, qdd, p)))(*args))


def _headline(c, verdict) -> str:
    tag = "VERDICT" if c is verdict else ("significant" if c.significant else "not significant")
    if c.overlaps:
        tag += f", overlaps {c.overlaps}"
    return (
        f"{c.spec} [{tag}]: removes {100 * c.error_reduction:.1f} % of the error "
        f"({100 * c.cv_error_reduction:.1f}\u00a0% held out, p\u00a0=\u00a0{c.p_value:.2g})"
    )


def _sentence(text: str) -> str:
    """`text` as a sentence: a capital first letter, a full stop at the end."""
    text = text.strip()
    return text[:1].upper() + text[1:] + ("" if text.endswith(".") else ".")


def _searched(key: str, u: Units) -> tuple[str, str]:
    """A searched parameter's axis label and unit."""
    return {
        "delay_ms": ("delay", "ms"),
        "vs": ("Stribeck velocity v_s", u.velocity),
        "width": ("smooth friction's width w", u.velocity),
        "order": ("cogging order N", "rad/m" if u is PRISMATIC else "periods/rev"),
    }.get(key, (key, ""))


def _search_panel(ax, c, u: Units):
    """rel_error over the candidate's searched parameter, on a logarithmic axis where the search
    spans decades (`spread_scale`: a delay searched from 0 to 100 ms on a symmetric-logarithmic
    one, its first milliseconds visible)."""
    values, errs = c.fit.search[c.effect]
    key = next(iter(values[0]))  # the searched parameter (order, vs, width, delay_ms)
    errs = np.asarray(errs, float)
    ok = np.isfinite(errs)
    if c.effect == "delay" and isinstance(values[0][key], list):  # one joint's delay at a time: a curve each
        arr = np.array([v[key] for v in values], float)
        kinds, counts = np.unique(arr, return_counts=True)
        joint = np.argmax(arr != kinds[np.argmax(counts)], axis=1)  # the joint whose delay differs
        x = arr[np.arange(len(arr)), joint]
        spread_scale(ax, x[ok])
        for j in np.unique(joint):
            on = ok & (joint == j)
            ax.plot(x[on], 100 * errs[on], ".-", lw=0.9, ms=2, label=f"joint {j + 1}")
        ax.legend()
    elif "combination" in values[0]:  # joints combined (a coupling): one point per combination
        x = np.arange(len(values), dtype=float)
        ax.plot(x[ok], 100 * errs[ok], "o", color="C0", ms=4)
        if len(values) <= 8:
            ax.set_xticks(x, [str(v["combination"]) for v in values])
    else:
        x = np.array([v[key] if not isinstance(v[key], list) else v[key][-1] for v in values], float)
        spread_scale(ax, x[ok])
        style = ".-" if np.all(np.diff(x[ok]) > 0) else "."  # a curve where the values are in order
        ax.plot(x[ok], 100 * errs[ok], style, color="C0", lw=0.9, ms=2 if style == ".-" else 4)
    best = int(np.nanargmin(np.where(ok, errs, np.nan)))
    ax.plot(x[best], 100 * errs[best], "o", color="C3", ms=4)
    if "combination" in values[0]:
        what = "joints combined" if len(values) <= 8 else "joints combined (the search's index)"
        unit, shown = "", str(values[best]["combination"])
    else:
        what, unit = _searched(key, u)
        shown = f"{x[best]:.4g} {unit}".rstrip()
    label = labelled(what, unit)
    ax.set_xlabel(f"{label} (only the best few evaluated exactly)" if (~ok).any() else label)
    ax.set_ylabel("rel_error [%]")
    ax.set_title(f"search over the whole record: best {shown}", loc="left")


HOW = {
    "velocity": "The residual binned against velocity: friction is a function of q̇ (a sign step, a slope, a V).",
    "position": "The residual against position: a load that depends on where the joint is.",
    "time": "The residual against time: a constant or slowly varying torque.",
    "shift": "A late torque leaves a residual ≈ delay × dτ/dt.",
    "acceleration": "The residual against acceleration: inertia.",
}


def evidence_panels(n_joints: int) -> int:
    """The panels of an `evidence_figure` on `n_joints` joints (at most)."""
    return n_joints + 1


def _evidence(base, c, verdict, title: str, reuse: dict | None) -> Figure:
    """The figure of `draw_evidence`, on a figure of the same shape from `reuse` when it has one."""
    data = base.data
    n = data.n_joints
    units = recording_units(data.rec)
    rows = data.rows
    q, qd, e = data.q[rows], data.qd[rows], base.residual
    has_search = c.fit is not None and c.effect in c.fit.search
    count = n + int(has_search)
    effect = c.fit.model.get(c.effect) if c.fit is not None else None
    how = HOW.get(effect.evidence, "") if effect is not None and c.mode is None else ""
    if effect is not None and c.mode is None and effect.evidence == "position" and "order" in effect.describe():
        how = "The residual against position modulo the cogging period."
    notes = [part for part in (c.note, "not proposed: " + "; ".join(c.problems) if c.problems else "", how) if part]
    ncols = min(count, WRAP)
    fig, grid = panels(
        -(-count // ncols),
        ncols,
        (5.0, 3.4),
        f"{title or Path(data.rec.path).name}: {base.model.spec} + {c.effect}\n{_headline(c, verdict)}",
        reuse,
        note=" ".join(_sentence(p) for p in notes),
    )
    axes = grid.ravel()
    for ax in axes[count:]:
        ax.set_axis_off()
    term = _term(c, data) if effect is not None and effect.linear else None
    for i in range(n):
        u = units[i]
        ax = axes[i]
        if c.mode is not None:
            _compliance_panel(ax, c, i, u)
            continue
        assert c.fit is not None and effect is not None  # a candidate without a mode is a fitted effect
        if effect.evidence == "shift":
            x = np.gradient(data.tau(base.delay, full=True)[:, i], data.work_dt)[rows // data.stride]
            shift = np.broadcast_to(np.asarray(c.fit.delay - base.delay, float), (data.n_joints,))[i]
            xl, y = labelled(f"dτ{i + 1}/dt", u.torque_rate), shift * x
        elif effect.evidence == "position" and "order" in effect.describe():
            N = float(effect.describe().get("orders", [effect.describe()["order"]])[-1])
            gears = data.rec.structure.transmission if effect.actuated else None  # (a motor's cogging: its angle)
            angle, name = (q, "q") if gears is None else (q @ gears.matrix.T, "θ")
            x, xl = np.mod(N * angle[:, i], 2 * np.pi), f"phase N·{name}{i + 1} mod 2π [rad] (N = {N:g})"
            assert term is not None  # every effect but the delay and the modes is linear
            y = term[:, i]
        else:
            x, xl = {
                "velocity": (qd[:, i], labelled(f"q̇{i + 1}", u.velocity)),
                "position": (q[:, i], labelled(f"q{i + 1}", u.position)),
                "time": (data.rec.t[rows], "t [s]"),
                "acceleration": (data.qdd[rows, i], labelled(f"q̈{i + 1}", u.acceleration)),
            }[effect.evidence]
            assert term is not None  # every effect but the delay and the modes is linear
            y = term[:, i]
        ax.plot(x, e[:, i], ".", ms=1.5, color="0.65", alpha=0.45, rasterized=True)
        bc, bm, bse = _binned(x, e[:, i])
        ax.errorbar(bc, bm, yerr=2 * bse, fmt="o-", ms=2.5, color="C3", lw=1.0, label="residual, binned mean ± 2 se")
        tc, tm, _ = _binned(x, y - np.mean(y) + np.mean(e[:, i]) if effect.evidence == "time" else y)
        ax.plot(tc, tm, color="C0", lw=1.6, label=f"fitted {c.effect} term (binned)")
        ax.axhline(0, color="k", lw=0.6)
        lim = np.percentile(np.abs(e[:, i]), 99.5) * 1.1
        ax.set_ylim(-lim, lim)
        red = c.detail.get("per_joint_error_reduction", [None] * n)[i]
        ax.set_title(f"joint {i + 1}" + (f": removes {100 * red:.1f} %" if red is not None else ""), loc="left")
        ax.set_xlabel(xl)
        ax.set_ylabel(labelled(f"residual {i + 1}", u.torque))
    # every joint's panel says the same: the legend once, on the first joint's
    axes[0].legend(loc="upper right" if c.mode is None else "lower left")
    if has_search:
        _search_panel(axes[n], c, units[0])
    tidy(axes[:count])
    return fig


@styled
def draw_evidence(base, c, verdict, title: str = "") -> Figure:
    """Why candidate `c` is (or is not) missing from the model fitted as `base`, per joint, plus
    its parameter search when it has one (`verdict`: the step's, None or another candidate). What
    the residual is plotted against is the effect's own `evidence`; the candidate's note, why it was
    not proposed and how to read the panels go in the note under them. `title` (the recording's
    name by default) heads the figure."""
    return _evidence(base, c, verdict, title, None)


@styled
def evidence_figure(base, c, verdict, out: Path, name: str, title: str = "", reuse: dict | None = None) -> str:
    """`draw_evidence` written as `out/name`; returns its path. `reuse`: figures of the same shape
    drawn on again (`panels`)."""
    return save(_evidence(base, c, verdict, title, reuse), out, name)


def _compliance_panel(ax, c, i: int, u: Units):
    from manus.adaptive.diagnosis.modes import band

    m = c.mode
    ax.loglog(m.freq[1:], m.measured[1:, i], color="k", lw=0.7, label="measured |θ̈/τ| (H1)")
    ax.loglog(m.freq[1:], m.rigid[1:, i], color="C0", lw=1.0, label="rigid fit")
    ax.loglog(m.freq[1:], m.fitted[1:, i], color="C3", lw=1.0, label=f"with a mode at {m.f_hz:.0f} Hz, ζ = {m.zeta:g}")
    ax.axvline(m.f_hz, color="C3", ls=":", lw=0.8)
    lo, hi = band(2 * m.freq[-1])
    ax.axvspan(lo, hi, color="C2", alpha=0.08, lw=0, label="band fitted (coherence-weighted)")
    ax.set_xlabel("frequency [Hz]")
    ax.set_ylabel(
        f"|q̈{i + 1}/τ{i + 1}| [1/{u.inertia}]" if "·" not in u.inertia else f"|q̈{i + 1}/τ{i + 1}| [1/({u.inertia})]"
    )
    ax.set_title(f"joint {i + 1}: frequency response, resonance peak: {'yes' if m.resonant else 'no'}", loc="left")


def evidence_figures(base, verdict, candidates, out: Path, prefix: str = "", title: str = "") -> dict[str, str]:
    """An `evidence_figure` per candidate (those fitted or with a mode): {effect: path}, drawn on
    figures reused between them."""
    reuse = {}
    try:
        return {
            c.effect: evidence_figure(base, c, verdict, out, f"{prefix}evidence_{c.effect}.png", title, reuse)
            for c in candidates
            if c.fit is not None or c.mode is not None
        }
    finally:
        close_all(reuse)


_AGAINST = {"position": "position", "velocity": "velocity", "position x direction": "position", RIPPLE: "position"}


@styled
def draw_unexplained(d, title: str = "") -> Figure | None:
    """What is left: the residual of the model (plus the verdict) of the joint with the most
    remaining structure, binned against the variable that explains most of it; None when the
    diagnosis tested none. The note under the plot says what the verdict on it rests on: smooth
    functions fitted on the training blocks and judged on the held-out ones."""
    u = d.unexplained or {}
    if not u.get("joint"):
        return None
    f = d.verdict.fit if d.verdict is not None and d.verdict.fit is not None else d.base
    data = f.data
    units = recording_units(data.rec)
    rows, j = data.rows, u["joint"] - 1
    i = (u.get("of_joint") or u["joint"]) - 1
    e = f.residual[:, j]
    what = u.get("variable") or "time"
    x = {
        "position": data.q[rows, i],
        "velocity": data.qd[rows, i],
        "position x direction": data.q[rows, i],
        RIPPLE: data.q[rows, i],
    }.get(what, data.rec.t[rows])
    verdict = "something no effect of the vocabulary explains" if u["significant"] else "no structure beyond noise"
    tests = u.get("tests", 0)
    share = getattr(d.context, "min_share", None)
    fig, axes = panels(
        1,
        1,
        (7.4, 4.0),
        f"{title or Path(data.rec.path).name}: left after {f.model.spec}: {verdict}\n"
        f"{what_removes(u)} removes {100 * u['fraction']:.0f} % held out "
        f"(p = {u['p_value']:.2g}, {tests} variables tested)",
        note=f"The verdict: a smooth function of each variable (each joint's position, velocity, position by "
        f"direction of motion, a torque ripple; time; a sinusoid at the residual's spectral peak) fitted on the "
        f"training blocks and judged on the held-out ones; structure counts when one is significant at "
        f"α = {d.alpha:g} over the {tests} tested (Bonferroni), removes at least {100 * UNEXPLAINED_MIN:.0f} % "
        "of the remaining error held out"
        + (f" and accounts for at least {100 * share:.2g} % of the torque (RMS)" if share else "")
        + ". A correlogram outside its band (the residual figure) shows a serially correlated residual, "
        "which by itself is not counted.",
    )
    ax = axes[0, 0]
    u_i, u_j = units[i], units[j]
    ylabel = labelled(f"residual {j + 1}", u_j.torque)
    if what == RIPPLE:  # the residual per unit of the model's torque: the ripple ε(q) where the torque is not small
        fitted = f.predicted()[:, i]
        big = np.abs(fitted) > 0.3 * np.sqrt(np.mean(fitted**2))
        x, e = x[big], e[big] / fitted[big]
        ylabel = f"residual {j + 1} / the model's τ{i + 1}" + (
            "" if u_i.torque == u_j.torque else f" [{u_j.torque}/{u_i.torque}]"
        )
    ax.plot(x, e, ".", ms=1.5, color="0.65", alpha=0.45, rasterized=True)
    if what == "position x direction":
        for sel, col, lab in ((data.qd[rows, i] > 0, "C3", "moving +"), (data.qd[rows, i] <= 0, "C0", "moving −")):
            bc, bm, bse = _binned(x[sel], e[sel])
            ax.errorbar(
                bc, bm, yerr=2 * bse, fmt="o-", ms=2.5, color=col, lw=1.0, label=f"residual {lab}, binned ± 2 se"
            )
    else:
        bc, bm, bse = _binned(x, e)
        ax.errorbar(bc, bm, yerr=2 * bse, fmt="o-", ms=2.5, color="C3", lw=1.0, label="residual, binned mean ± 2 se")
    ax.axhline(0, color="k", lw=0.6)
    against = _AGAINST.get(what)
    if against == "position":
        ax.set_xlabel(labelled(f"q{i + 1}, position of joint {i + 1}", u_i.position))
    elif against == "velocity":
        ax.set_xlabel(labelled(f"q̇{i + 1}, velocity of joint {i + 1}", u_i.velocity))
    else:
        ax.set_xlabel("t [s]")
    ax.set_ylabel(ylabel)
    ax.legend()
    tidy(axes)
    return fig


def unexplained_figure(d, out: Path, name: str, title: str = "") -> str | None:
    """`draw_unexplained` written as `out/name`: its path, or None when there is no such figure."""
    fig = draw_unexplained(d, title)
    return None if fig is None else save(fig, out, name)


def evidence_there(d, out: Path, stem: str, painter: Painter) -> Job:
    """The painter's share of a diagnosis's evidence figures (`_shares`), started now: a command
    hands them over as soon as the candidates are judged, and `diagnosis_figures` draws the rest."""
    return painter.draw(evidence_figures, d.base, d.verdict, _shares(d, painter)[0], out, f"{stem}_")


def _shares(d, painter: Painter) -> tuple[list, list]:
    """A diagnosis's candidates with an evidence figure (fitted, or with a mode), split between
    the painter (the first half with a worker, none without) and this process."""
    shown = [c for c in d.candidates if c.fit is not None or c.mode is not None]
    half = len(shown) // 2 if painter.remote else 0
    return shown[:half], shown[half:]


def diagnosis_figures(
    d, out: Path, stem: str, painter: Painter | None = None, resid: Job | None = None, there: Job | None = None
) -> dict:
    """A diagnosis's figures: the residual (`resid`: already being drawn), one evidence figure per
    candidate, what is left. With a `painter`, the first half of the evidence figures are drawn
    by it (`there`: already being drawn, `evidence_there`) while this process draws the rest."""
    painter = painter or Painter(0)
    resid = resid or painter.draw(resid_figure, d.base, out, f"{stem}_resid.png")
    there = there or evidence_there(d, out, stem, painter)
    theirs, mine = _shares(d, painter)
    here = evidence_figures(d.base, d.verdict, mine, out, f"{stem}_")
    left = unexplained_figure(d, out, f"{stem}_unexplained.png")
    drawn = {**there.result(), **here}
    return {
        "resid": resid.result(),
        "evidence": {c.effect: drawn[c.effect] for c in theirs + mine},
        "unexplained": left,
    }
