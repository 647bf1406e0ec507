"""`manus fit REC --model EFFECTS`: identify a model's parameters from a recording (inverse
dynamics, `manus.adaptive.identify`), report each with its standard deviation and the rel_error, and draw the
`compare` figure: measured against predicted torque, and measured positions against the fitted
model simulated in the JAX simulator (`manus.experiments.freerun`: closed loop over the whole
recording through a controller the recording names, otherwise open loop on the recorded torque in
windows restarted from the measured state)."""

from __future__ import annotations

from pathlib import Path

from manus.runs.args import add_common, add_model_options, load_recording
from manus.runs.text import note, table

NAME = "fit"
HELP = "identify a model's parameters from a recording (inverse dynamics), with std, rel_error and a compare figure"


def add_arguments(p) -> None:
    add_model_options(p)
    p.add_argument(
        "--open-loop",
        action="store_true",
        help="simulate open loop on the recorded torque (in windows restarted from the measured state) even when "
        "the recording names its controller and reference",
    )
    p.add_argument(
        "--no-sim", action="store_true", help="skip the free-run simulation (the figure shows the torque only)"
    )
    p.add_argument("--no-figures", action="store_true", help="skip the figure (and the free run)")
    add_common(p)


def run(args) -> dict:
    from manus.adaptive import fit
    from manus.experiments.freerun import free_run_or_reason, nrmse_fit
    from manus.runs.figures.fit import compare_figure

    rec = load_recording(args)
    f = fit(rec, args.model, cutoff_hz=args.cutoff, method=args.method)
    out = f.report()
    out["fit_percent"] = {"torque": nrmse_fit(f.data.tau(f.delay), f.predicted()).tolist()}
    if rec.time_base:  # repeated rows, jittered stamps or a resampled rate found and repaired as it was read
        out["time_base"] = rec.time_base.report()
    if "urdf_values" in out:  # a serial chain: the physically consistent stage of the fit, in full
        out["consistent"] = f.consistency or {"error": "physically consistent parameters are a rigid model's"}
    if not args.no_figures:
        if args.no_sim:
            run_ = "skipped (--no-sim)"
        else:
            note("free run of the fitted model in the simulator ...")
            run_ = free_run_or_reason(f, args.open_loop)
        if isinstance(run_, str):
            out["free_run"] = {"mode": None, "how": run_}
        else:
            out["free_run"] = run_.report()
            out["fit_percent"]["position"] = run_.fit_q.tolist()
        stem = Path(rec.path).stem
        out["figures"] = {"compare": compare_figure(f, run_, args.out, f"compare_{stem}.png")}
    return out


def render(r: dict) -> str:
    rows = []
    urdf = r.get("urdf_values")  # a serial chain: each rigid base parameter as its URDF has it
    for k, p in r["params"].items():
        std = p["std"]
        rel = f"{100 * std / abs(p['value']):.2f}" if std is not None and p["value"] else "-"
        rows.append(
            [k, f"{p['value']:.6g}", "-" if std is None else f"{std:.3g}", rel]
            + ([f"{urdf[k]:.6g}" if k in urdf else ""] if urdf else [])
        )
    lines = [
        f"model {r['spec']}: rel_error {100 * r['rel_error']:.2f} % on {r['samples']} rows "
        f"(torque low-passed at {r['cutoff_hz']:.1f} Hz, {100 * r['standstill_excluded']:.1f} % left out at "
        "standstill)",
        f"  method {r['method']}: {r['method_why']}",
        *([output_error_line(r["output_error"])] if "output_error" in r else []),
        f"  cut-off: {r['cutoff_note']}; command hold: {r['hold']}",
        *([f"  gaps: {r['gaps']}"] if r.get("gaps") else []),
        table(rows, ["parameter", "value", "std", "std %"] + (["in the URDF"] if urdf else [])),
    ]
    regrouped = {k: v for k, v in r.get("base_parameters", {}).items() if k != v}
    if regrouped:  # a serial chain: the base parameters that are combinations of standard ones
        lines.append("  base parameters (identifiable combinations of the standard ones; the others are themselves):")
        lines += [f"    {k} = {v}" for k, v in regrouped.items()]
    c = r.get("consistent")
    if c is not None and "error" in c:
        lines.append(f"  physically consistent: none found ({c['error']})")
    elif c is not None:
        far = {k: v for k, v in c["moved_std"].items() if abs(v) >= 1}
        lines.append(
            "  physically consistent (each link's pseudo-inertia positive semidefinite, armatures and friction "
            "within their bounds): "
            + (
                "the estimate is consistent already"
                if c["already"]
                else f"the estimate breaks physics (rel_error {100 * c['ls_rel_error']:.2f} %): the parameters "
                f"above are the closest consistent set, rel_error {100 * c['rel_error']:.2f} %"
                + (
                    ", moving " + ", ".join(f"{k} by {v:+.1f} std" for k, v in far.items())
                    if far
                    else ", every parameter within one standard deviation"
                )
            )
        )
        lines.append(
            "    link masses " + ", ".join(f"{x['mass']:.4g}" for x in c["links"]) + " kg (held near the URDF's)"
        )
    for k, v in r.get("nonlinear", {}).items():
        shown = ", ".join(f"{x:.6g}" for x in v) if isinstance(v, (list, tuple)) else f"{v:.6g}"
        lines.append(f"  {k} = {shown} (searched or fixed)")
    for v in r.get("violations", []):
        lines.append(f"  {'the estimate ' if (c or {}).get('moved') else ''}breaks physics: {v}")
    if r.get("redundant"):
        lines.append(f"  redundant (explained by the others, set to 0): {', '.join(r['redundant'])}")
    fits = r["fit_percent"]
    lines.append("  torque fit (NRMSE) per joint: " + ", ".join(f"{x:.1f} %" for x in fits["torque"]))
    if "free_run" in r:
        fr = r["free_run"]
        lines.append(f"  free run: {fr['how']}")
        if "position" in fits:
            lines.append("    position fit per joint: " + ", ".join(f"{x:.2f} %" for x in fits["position"]))
        if "tracking_error_fit_percent" in fr:
            lines.append(
                "    tracking-error fit per joint: " + ", ".join(f"{x:.1f} %" for x in fr["tracking_error_fit_percent"])
            )
    for k, v in r.get("figures", {}).items():
        lines.append(f"  figure ({k}): {v}")
    return "\n".join(lines)


def output_error_line(oe: dict) -> str:
    """The output-error fit's positions, beside those of the estimate LS and IV gave."""
    rms = ", ".join(f"{x:.3g}" for x in oe["position_rms"])
    before = oe["compared"]
    was = (
        f"; {before['method'].upper()}'s parameters {100 * before['position_rel_error']:.2f} %"
        if before["position_rel_error"] is not None
        else ""
    )
    return (
        f"  output error: simulated positions off by {100 * oe['position_rel_error']:.2f} % of the windows' motion "
        f"(RMS {rms} per joint, encoder step {oe['encoder_step']:.3g}){was}; {oe['windows']} windows of "
        f"{oe['window_s']:.3g} s from the measured state, started from {oe['start']}"
    )
