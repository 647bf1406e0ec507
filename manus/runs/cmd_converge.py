"""`manus converge`: parameter-convergence trials of the Slotine–Li adaptive controller (thesis
App. C), a batch of trials at once (`manus.experiments.convergence` says what a trial is and what
is reported), with the figures of the tracking and of the estimates."""

from __future__ import annotations

import time

from manus.experiments.convergence import TRAJECTORIES
from manus.runs.args import add_common, add_plant_options, build_plant, parse_pairs
from manus.runs.progress import elapsed, note
from manus.runs.text import table

NAME = "converge"
HELP = "parameter-convergence trials of the Slotine-Li adaptive controller (thesis App. C), vmapped"


def add_arguments(p) -> None:
    p.add_argument(
        "--trajectory",
        choices=TRAJECTORIES,
        default=None,
        help="thesis eqs. C.13-C.14 (complex, the default on manus2), C.11-C.12 (benign), or a "
        "multi-sine (the default elsewhere)",
    )
    p.add_argument(
        "--model",
        default="rigid",
        metavar="EFFECTS",
        help="effects in the controller's regressor, e.g. rigid,viscous,coulomb (default rigid)",
    )
    p.add_argument(
        "--law",
        choices=("gradient", "composite"),
        default="gradient",
        help="the adaptation law: Slotine-Li's gradient law or composite adaptation",
    )
    p.add_argument(
        "--form",
        choices=("slotine-li", "thesis"),
        default="slotine-li",
        help="regressor: C(q, qd) qd_r (slotine-li) or the thesis's qd_r² terms",
    )
    p.add_argument(
        "--estimator",
        default="kalman_cv",
        metavar="NAME",
        help="velocity estimator (estimators.NAMES; default kalman_cv; the thesis used first_difference)",
    )
    p.add_argument("--trials", type=int, default=200)
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--init-spread", type=float, default=0.5, help="initial estimates within ±this fraction")
    p.add_argument("--gain-spread", type=float, default=0.25, help="gains scaled within ×/÷ (1 + this)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--uncompensated",
        action="store_true",
        help="no timing compensation (lead = velocity lag = 0): the thesis's controller",
    )
    p.add_argument(
        "--gain",
        action="append",
        default=[],
        metavar="KNOB=VALUE",
        help="a controller setting: lam, kd, boundary, min_inertia, lead, velocity_lag, and for the "
        "composite law bandwidth, weight, forgetting (repeatable)",
    )
    p.add_argument(
        "--gamma",
        action="append",
        default=[],
        metavar="PARAM=VALUE",
        help="the adaptation gain of one parameter, e.g. --gamma b1=30 (repeatable)",
    )
    add_common(p)
    add_plant_options(p, truth_default="rigid,viscous,coulomb", robot=True)
    p.set_defaults(torque_noise=0.005)


def run(args) -> dict:
    from manus.adaptive.slotine_li import SlotineLi
    from manus.experiments.convergence import base_summary, controller_for, run_trials, summarize, trajectory
    from manus.plants.effects import Model
    from manus.plants.errors import ManusError
    from manus.runs.figures.converge import plot_estimates, plot_tracking

    plant = build_plant(args)
    structure = plant.model.structure
    # a serial robot adapts in pseudo-inertia coordinates, where its projection keeps every link consistent
    model = Model(structure.adaptive_form(), args.model)
    if args.trajectory is None:
        args.trajectory = "complex" if model.structure.thesis_arm else "multisine"
    reference = trajectory(args.trajectory, model)
    gains: dict[str, float | dict[str, float]] = dict(parse_pairs(args.gain, "--gain"))
    if args.gamma:
        gains["gamma"] = parse_pairs(args.gamma, "--gamma")
    controller = controller_for(plant, model, args.law, args.estimator, args.form, args.uncompensated, **gains)
    assert isinstance(controller, SlotineLi)  # controller_for makes a Slotine–Li law
    note(
        f"{args.trials} trials of {args.seconds:g} s on the {args.trajectory} trajectory: truth {plant.model.spec}, "
        f"model {model.spec}, {args.law} law, {args.estimator} ..."
    )
    start = time.perf_counter()
    with elapsed("compiling and running the trials"):
        tr = run_trials(
            plant, controller, reference, args.trials, args.seconds, args.init_spread, args.gain_spread, args.seed
        )
    spent = time.perf_counter() - start
    if tr.stopped.all():
        raise ManusError("every trial stopped itself on a non-finite value: nothing to report")
    result = summarize(tr)
    if model.structure.standard_form is not model.structure:  # a chain in other coordinates: its base parameters
        result["base_params"] = base_summary(tr, model.structure)
    title = f"{args.trajectory}: truth {plant.model.spec}, model {model.spec}, {args.law}, {args.estimator}"
    result["figures"] = {
        "tracking": plot_tracking(tr, args.out / f"converge_{args.trajectory}_tracking.png", title),
        "estimates": plot_estimates(tr, args.out / f"converge_{args.trajectory}_estimates.png", title),
    }
    result.update(
        trajectory=args.trajectory,
        truth=plant.model.spec,
        model=model.effect_names,
        law=args.law,
        form=args.form,
        estimator=args.estimator,
        seconds=float(tr.t[-1] + plant.dt),
        lead_s=float(controller.lead),
        velocity_lag_s=float(controller.velocity_lag),
        elapsed_s=spent,
        trials_per_s=args.trials / spent,
    )
    return result


def render(r: dict) -> str:
    rows = []
    for name, p in r["params"].items():
        err = "" if p["error"] is None else f"{100 * p['error']:+.2f} %"
        t5 = "never" if p["t_within_5pct"] is None else f"{p['t_within_5pct']:.2f} s"
        rows.append([name, f"{p['truth']:.4g}", f"{p['final']:.4g} ± {p['final_std']:.2g}", err, t5])
    ex = r["excitation"]
    lines = [
        f"{r['trials']} trials, {r['seconds']:g} s of the {r['trajectory']} trajectory "
        f"(truth {r['truth']}; model {','.join(r['model'])}; {r['law']} law; {r['estimator']}) "
        f"in {r['elapsed_s']:.1f} s",
        table(rows, ["param", "truth", "final (mean ± std)", "error", "t within 5 %"]),
        f"excitation: smallest eigenvalue of ∫YᵀY dt = {ex['lambda_min']:.3g} at the end"
        + (f", {ex['lambda_min_at_1s']:.3g} after 1 s" if ex["lambda_min_at_1s"] is not None else ""),
        "tracking error RMS per joint: " + ", ".join(f"{x:.4f} rad" for x in r["tracking_rms"]),
    ]
    if "base_params" in r:  # a serial chain: what the torque can determine
        rows = [
            [
                k,
                f"{b['truth']:.4g}",
                f"{b['final']:.4g} ± {b['final_std']:.2g}",
                "" if b["error"] is None else f"{100 * b['error']:+.2f} %",
            ]
            for k, b in r["base_params"].items()
        ]
        lines += [
            "base parameters (the combinations the torque determines) of the final estimates:",
            table(rows, ["base", "truth", "final (mean ± std)", "error"]),
        ]
    if r["stopped_trials"]:
        lines.append(f"{r['stopped_trials']} trial(s) stopped on a non-finite value (left out above)")
    lines += [f"figures: {r['figures']['tracking']}", f"         {r['figures']['estimates']}"]
    return "\n".join(lines)
