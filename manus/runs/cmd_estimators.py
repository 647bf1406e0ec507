"""`manus estimators REC`: every velocity estimator on a recording, scored and (optionally) tuned.

The model-based estimators (kalman_model, luenberger_model) are never ranked on a model this
recording did not identify: by default their model (`--model`, default rigid,viscous,coulomb) is
fitted on the recording first, as `manus fit REC --model EFFECTS` fits it (`manus.adaptive.fit`,
its default cut-off and method); `--model-from FIT.json` takes the model and parameters of a fit's
JSON instead (what `manus fit ... --json` prints: its `spec` and `params`, checked to be of this
recording's structure and joint count); `--param NAME=VALUE` then sets single parameters by hand
(every one given: no fit). A fitted parameter below its physical bound by less than two standard
deviations is set at the bound (`at_bounds`). The report says which ("model": `from`, `spec`,
`params`, `rel_error`, `at_bound`). Where the recording cannot identify the model (the fit
refuses it) or its parameters break physics, the model-based estimators are left out of the
ranking with the reason ("left_out"), the others still ranked.
"""

from __future__ import annotations

from manus.runs.args import add_common, add_source_options, read_recording
from manus.runs.text import estimators_text

NAME = "estimators"
HELP = "compare every velocity estimator on a recording (against its true velocity, or the offline reference)"


def add_arguments(p) -> None:
    add_source_options(p)  # REC, --robot, and how to read a table or bag of one's own
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
        "--model",
        metavar="EFFECTS",
        help="the model of the model-based estimators, fitted on the recording first (default rigid,viscous,coulomb)",
    )
    p.add_argument(
        "--model-from",
        metavar="FIT.json",
        help="the model and parameters of a fit instead: the JSON `manus fit REC --model EFFECTS --json` prints "
        "(of a recording of the same structure and joint count)",
    )
    p.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a parameter of that model by hand, e.g. --param M1=95.1 (repeatable; the others fitted; "
        "every one given: no fit)",
    )
    p.add_argument("--no-figures", action="store_true", help="skip the figures")
    add_common(p)


def run(args) -> dict:
    from manus.estimators import NAMES
    from manus.plants.effects import parse_effects
    from manus.plants.errors import ManusError
    from manus.runs.analyses import estimators_recording
    from manus.runs.args import parse_params

    names = NAMES if not args.only else tuple(n.strip() for n in args.only.split(",") if n.strip())
    unknown = [n for n in names if n not in NAMES]
    if unknown:
        raise ManusError(f"unknown estimator {unknown[0]!r}: the estimators are {', '.join(NAMES)}")
    if args.cutoff <= 0:
        raise ManusError("--cutoff must be positive")
    if args.model and args.model_from:
        raise ManusError("--model and --model-from: give one (a fit's JSON names its model)")
    if args.model:
        parse_effects(args.model)  # unknown names, duplicates: refused before the file is read
    by_hand = parse_params(args.param)
    rec = read_recording(args)
    a = estimators_recording(rec, names, args.tune, args.cutoff, args.model, args.model_from, by_hand)
    if not args.no_figures:
        from manus.runs.figures.estimators import estimator_figures

        a.report["figures"] = estimator_figures(rec, a.report, a.estimates, args.out)
    return a.report


def render(r: dict) -> str:
    return estimators_text(r)
