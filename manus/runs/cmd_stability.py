"""`manus stability`: the impedance limits of chapter 4 and Appendix D, reproduced.

The stability map over a (b_c, k) grid from the thesis's step test on the compliant, quantized,
delayed axis (both thresholds, like Fig. 4-25) with the linear Type 1 curves drawn in; the poles
of eq. 4.1; the Type 1 curves against the springs of table 4.2; the largest negative damping that
stays stable; the maps at 100 Hz against the springs of Appendix D; how the thresholds move with
the delay, the quantization step and the sampling rate; and how the Type 2 boundary depends on
the PSD normalization. See `manus.experiments.stability` for the models and criteria.
"""

from __future__ import annotations

import time

import numpy as np

from manus.plants.errors import ManusError
from manus.runs.args import add_common
from manus.runs.progress import note
from manus.runs.text import table

NAME = "stability"
HELP = "impedance limits: Type 1/Type 2 stability map, negative damping, 100 Hz, sensitivity (thesis ch. 4, App. D)"


def _range(text: list[float], what: str, positive: bool = False) -> np.ndarray:
    lo, hi, step = text
    if not (hi > lo and step > 0) or (positive and lo <= 0):
        raise ManusError(
            f"--{what} {lo:g} {hi:g} {step:g}: expected MIN < MAX and STEP > 0" + (" with MIN > 0" if positive else "")
        )
    return np.arange(lo, hi + step / 2, step)


def add_arguments(p) -> None:
    add_common(p)
    p.add_argument(
        "--b-c",
        nargs=3,
        type=float,
        default=[-2.0, 40.0, 0.5],
        metavar=("MIN", "MAX", "STEP"),
        help="controller damping grid [N·s/m] (default -2 40 0.5)",
    )
    p.add_argument(
        "--k",
        nargs=3,
        type=float,
        default=[100.0, 10000.0, 100.0],
        metavar=("MIN", "MAX", "STEP"),
        help="controller stiffness grid [N/m] (default 100 10000 100)",
    )
    p.add_argument("--cluster", metavar="tcp://HOST:PORT", help="run the sweeps on this Dask scheduler")
    p.add_argument("--no-sensitivity", action="store_true", help="skip the delay/quantizer/rate sensitivity")
    p.add_argument("--no-appendix-d", action="store_true", help="skip the 100 Hz maps of Appendix D")


def run(args) -> dict:
    from manus.experiments.stability import analysis, sweep
    from manus.experiments.stability.search import stability_map
    from manus.experiments.stability.sensitivity import sensitivity
    from manus.experiments.stability.steptest import StepTest, line_amplitude
    from manus.plants.closed_loop import simulate
    from manus.runs.figures import stability as figures

    b_cs, ks = _range(args.b_c, "b-c"), _range(args.k, "k", positive=True)
    cluster = sweep.client_for(args.cluster) if args.cluster else None
    test = StepTest()
    out = {
        "model": {
            "structure": "axis",
            "truth": test.plant().model.spec,
            "M1": test.mass,
            "b1": test.damping,
            "quantum": test.quantum,
            "rate_hz": test.rate_hz,
            "step": test.step,
            "seconds": test.seconds,
            "psd_threshold": 1e-6,
            "psd_line_amplitude": line_amplitude(1e-6),
        },
        "eq41_poles": analysis.eq41_poles(),
        "figures": {},
    }
    try:
        note(f"stability map: {b_cs.size} x {ks.size} = {b_cs.size * ks.size} step tests ...")
        t0 = time.perf_counter()
        smap = stability_map(test, b_cs, ks, cluster)
        seconds = time.perf_counter() - t0
        note("Type 1 curves of the linear model ...")
        curves = analysis.type1_curves(np.unique(np.round(b_cs)) + 0.0)  # every 1 N·s/m: smooth enough
        out["type1"] = curves
        out["map"] = analysis.map_summary(smap, test.linear(), test.rate_hz) | {
            "seconds": seconds,
            "points_per_s": smap.kinds.size / seconds,
        }
        out["psd_conventions"] = analysis.psd_conventions(test, smap)
        out["figures"]["map"] = figures.stability_map(smap, curves, args.out)
        out["figures"]["type1"] = figures.type1_curves(curves, args.out)
        example = analysis.type2_example(smap)
        if example:
            k, b_c = example
            traj = simulate(test.plant(), test.controller(k, b_c), test.reference(), test.seconds)
            out["type2_example"] = {"k": k, "b_c": b_c}
            out["figures"]["type2_response"] = figures.step_response(traj, test, k, b_c, args.out)
        note("negative damping ...")
        out["negative_damping"] = analysis.negative_damping(test, cluster=cluster)
        if not args.no_appendix_d:
            note("Appendix D: 100 Hz maps ...")
            summary, maps = analysis.appendix_d(
                np.arange(-2.0, 20.01, 1.0), np.arange(50.0, 3000.1, 25.0), cluster=cluster
            )
            out["appendix_d"] = summary
            out["figures"]["appendix_d"] = figures.appendix_d(maps, summary, args.out)
        if not args.no_sensitivity:
            note("sensitivity to delay, quantizer and sampling rate ...")
            out["sensitivity"] = sensitivity(test, cluster=cluster)
            out["figures"]["sensitivity"] = figures.sensitivity(out["sensitivity"], args.out)
    finally:
        if cluster is not None:
            cluster.close()
    return out


def render(r: dict) -> str:
    p = r["eq41_poles"]
    poles = ", ".join(f"{a:.2f}{b:+.2f}i" if b else f"{a:.2f}" for a, b in p["poles"])
    m = r["map"]
    lines = [
        f"eq. 4.1 poles at k = {p['k']:g}, b_c = {p['b_c']:g}: {poles} (thesis: -186.5, -1.7±9.9i; "
        f"{p['natural_hz']:.2f} Hz, ζ = {p['damping_ratio']:.3f})",
        f"stability map: {m['points']} step tests in {m['seconds']:.1f} s ({m['points_per_s']:.0f} points/s); "
        f"stable {100 * m['stable_fraction']:.0f} %",
        f"  Type 1 edge slope {m['type1_slope'] or float('nan'):+.0f} N/m per N·s/m, Type 2 edge slope "
        f"{m['type2_slope'] or float('nan'):+.0f}"
        + (f"; widest at b_c = {m['peak']['b_c']:g}, k = {m['peak']['k']:g}" if m["peak"] else ""),
    ]
    t1, t2 = m["type1_boundary"], m["type2_boundary"]
    pick = lambda pts: pts[:: max(1, len(pts) // 6)]
    lines.append(
        table(
            [[f"{q['b_c']:g}", f"{q['k']:g}", "Type 1"] for q in pick(t1)]
            + [[f"{q['b_c']:g}", f"{q['k']:g}", "Type 2"] for q in pick(t2)],
            ["b_c", "k limit", "edge"],
        )
    )
    c = r["type1"]
    lines.append(
        "linear Type 1 k_max (eq. 4.1, 1 ms delay): "
        + ", ".join(
            f"b_c={b:g}: {k:.0f}"
            for b, k in zip(c["b_c"], c["continuous"]["0"], strict=True)
            if k is not None and b in (0, 5, 10, 20, 40)
        )
    )
    nd = r["negative_damping"]
    lines.append(
        f"largest stable negative damping: {nd['limit']:.3f} N·s/m at k = {nd['at_k']:g} "
        f"(linear sampled {nd['linear_sampled'][nd['k'].index(nd['at_k'])]:.3f}; thesis {nd['thesis']:g})"
    )
    if "appendix_d" in r:
        for spring, v in r["appendix_d"]["springs"].items():
            row = {q["b_c"]: q["k"] for q in v["type1_boundary"]}
            at = [b for b in (5.0, 10.0, 15.0) if b in row]
            lines.append(
                f"{r['appendix_d']['rate_hz']:g} Hz, k_env = {spring} N/m: Type 1 limit "
                + ", ".join(f"b_c={b:g}: {row[b]:g} (linear {v['linear_sampled'][v['b_c'].index(b)]:.0f})" for b in at)
            )
    if "sensitivity" in r:
        for t in r["sensitivity"]["tables"]:
            for row in t["rows"]:
                lines.append(
                    f"  {t['label']} = {row['value']:g}: "
                    + "  ".join(
                        f"{q['probe']}: {'-' if q['limit'] is None else format(q['limit'], '.4g')} ({q['kind']})"
                        for q in row["probes"]
                    )
                )
        lines += [f"  [{c['verdict']}] {c['claim']} ({c['reading']})" for c in r["sensitivity"]["claims"]]
    lines += [f"figure: {f}" for f in r["figures"].values()]
    return "\n".join(lines)
