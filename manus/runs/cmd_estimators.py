"""`manus estimators REC`: every velocity estimator on a recording, scored and (optionally) tuned."""

from __future__ import annotations

from manus.runs.args import add_common, add_robot_option, read_recording
from manus.runs.text import note, table

NAME = "estimators"
HELP = "compare every velocity estimator on a recording (against its true velocity, or the offline reference)"


def add_arguments(p) -> None:
    p.add_argument("recording", metavar="REC", help="a recording (.csv, .npz, or an EMPS .mat file)")
    add_robot_option(p)
    p.add_argument(
        "--tune",
        action="store_true",
        help="tune each estimator's knob on the recording first (against the true velocity, "
        "else by the whiteness of its prediction residual)",
    )
    p.add_argument("--only", metavar="NAMES", help="a comma-separated subset of the estimators")
    p.add_argument(
        "--cutoff",
        type=float,
        default=30.0,
        metavar="HZ",
        help="corner of the offline zero-phase reference when there is no true velocity (default 30)",
    )
    p.add_argument(
        "--model", metavar="EFFECTS", help="the model of the model-based estimators (default rigid,viscous,coulomb)"
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a parameter of that model, e.g. --param M1=95.1 (repeatable; default the effects' own)",
    )
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_common(p)


def run(args) -> dict:
    from manus.estimators import NAMES
    from manus.estimators.compare import compare
    from manus.plants import Model
    from manus.plants.errors import ManusError
    from manus.runs.args import parse_params
    from manus.runs.figures.estimators import estimator_figures

    names = NAMES if not args.only else tuple(n.strip() for n in args.only.split(",") if n.strip())
    unknown = [n for n in names if n not in NAMES]
    if unknown:
        raise ManusError(f"unknown estimator {unknown[0]!r}: the estimators are {', '.join(NAMES)}")
    if args.cutoff <= 0:
        raise ManusError("--cutoff must be positive")
    rec = read_recording(args)
    model_knobs: dict[str, str | Model | dict[str, float]] = {"structure": rec.structure_name}
    if args.model or rec.structure_name == "urdf":  # a serial chain's model is built on the recording's robot
        from manus.estimators.registry import NOMINAL_MODEL

        model_knobs["model"] = Model(rec.structure, args.model or NOMINAL_MODEL)
    if args.param:
        model_knobs["params"] = parse_params(args.param)
    note(
        f"{rec.path}: {len(rec)} samples of {rec.n_joints} joint(s) at {rec.sample_rate_hz:g} Hz, "
        f"{'with' if rec.has_truth else 'without'} a true velocity" + (", tuning each knob" if args.tune else "")
    )
    report, estimates = compare(
        rec, names, args.tune, args.cutoff, model_knobs, progress=lambda name: note(f"  {name} ...")
    )
    if rec.time_base:  # repeated rows, jittered stamps or a resampled rate found and repaired as it was read
        report["time_base"] = rec.time_base.report()
    if not args.no_figures:
        report["figures"] = estimator_figures(rec, report, estimates, args.out)
    return report


def render(r: dict) -> str:
    def f(x, spec=".3g"):
        return "-" if x is None else format(x, spec)

    def knob(e):
        k = e.get("knob")
        return "" if k is None else f"{k['name']}={k['value']:.3g}" + (" (range end)" if k.get("at_limit") else "")

    rows = [
        [
            e["name"],
            knob(e),
            f(e["rms_error"]),
            f((e["moving"] or {}).get("rms_error")),
            f((e["still"] or {}).get("rms_error")),
            f(e["max_error"]),
            f(e["lag_ms"], ".2f"),
            f(e["noise_50hz"]),
        ]
        for e in r["estimators"]
    ]
    against = "the true velocity" if r["truth"] else f"the {r['reference']} reference"
    lines = [
        f"{r['recording']}: {r['samples']} samples, {r['joints']} joint(s); errors against {against}",
        table(
            rows,
            [
                "estimator",
                "knob" + (" (tuned)" if r["tuned"] else ""),
                "RMS",
                "RMS moving",
                "RMS still",
                "max",
                "lag [ms]",
                "noise >50 Hz",
            ],
        ),
        f"best: {r['best']}",
    ] + ([f"gaps: {r['gaps']}"] if r.get("gaps") else [])
    for name, path in (r.get("figures") or {}).items():
        lines.append(f"figure ({name}): {', '.join(path) if isinstance(path, list) else path}")
    return "\n".join(lines)
