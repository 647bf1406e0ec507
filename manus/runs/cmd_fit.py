"""`manus fit REC --model EFFECTS`: identify a model's parameters from a recording (inverse
dynamics, `manus.adaptive.identify`), report each with its standard deviation and the rel_error, and draw the
`compare` figure: measured against predicted torque, and measured positions against the fitted
model simulated in the JAX simulator (`manus.experiments.freerun`: closed loop over the whole
recording through a controller the recording names, otherwise open loop on the recorded torque in
windows restarted from the measured state)."""

from __future__ import annotations

from pathlib import Path

from manus.runs.args import add_common, add_model_options, load_recording
from manus.runs.text import fit_text

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
    from manus.runs.analyses import fit_recording
    from manus.runs.figures.fit import compare_figure

    rec = load_recording(args)
    a = fit_recording(rec, args.model, cutoff_hz=args.cutoff, method=args.method)
    if not args.no_figures:
        if args.no_sim:
            a.skip_run("skipped (--no-sim)")
        else:
            a.simulate(args.open_loop)
        stem = Path(rec.path).stem
        a.report["figures"] = {"compare": compare_figure(a.fit, a.run, args.out, f"compare_{stem}.png")}
    return a.report


def render(r: dict) -> str:
    return fit_text(r)
