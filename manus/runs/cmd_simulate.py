"""`manus simulate`: simulate a plant under closed-loop control and write the recording."""

from __future__ import annotations

from pathlib import Path

from manus.runs.args import add_json, add_plant_options, build_plant, output_file
from manus.runs.progress import note

NAME = "simulate"
HELP = (
    "simulate the arm, axes or a serial robot (--robot FILE.urdf) under control and write a recording with "
    "true velocities"
)


def add_arguments(p) -> None:
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--reference", choices=("multisine", "benign", "complex", "hold"), default="multisine")
    p.add_argument("--amplitude", type=float, default=0.15, help="multi-sine amplitude per joint [rad or m]")
    p.add_argument("--seed", type=int, default=0, help="multi-sine phases and plant noise")
    p.add_argument(
        "--stiffness",
        type=float,
        default=None,
        help="impedance controller K [N·m/rad] (default 30; a serial robot's PD around its computed "
        "torque: a 5 Hz loop on each joint's inertia)",
    )
    p.add_argument(
        "--damping",
        type=float,
        default=None,
        help="impedance controller B [N·m·s/rad] (default 1; a serial robot's: critically damped)",
    )
    p.add_argument(
        "--out",
        type=output_file(".csv", ".npz"),
        default=Path("runs/out/simulated.csv"),
        metavar="FILE",
        help="the recording to write (.csv or .npz); a figure goes beside it (.png)",
    )
    add_json(p)
    add_plant_options(p, robot=True)


def run(args) -> dict:
    import numpy as np

    from manus.experiments.simulated import controller_for, simulated_recording, tracking_rms
    from manus.plants import recording
    from manus.plants.errors import ManusError
    from manus.plants.references import reference_named
    from manus.plants.simulator import workspace_centre
    from manus.runs.figures.common import plot_recording

    if args.seconds <= 0:
        raise ManusError("--seconds must be positive")
    plant = build_plant(args)
    centre = np.asarray(workspace_centre(plant.model))
    arm = args.structure == "manus2" and not args.robot
    reference = reference_named(args.reference, centre, arm, args.amplitude, args.seed)
    controller, how = controller_for(plant, bool(args.robot), args.stiffness, args.damping)
    note(f"simulating {args.seconds:g} s of {plant.model.spec} at {plant.rate_hz:g} Hz ...")
    rec = simulated_recording(plant, controller, how, reference, args.reference, args.seconds, args.seed, args.counts)
    path = recording.write(rec, args.out)
    rec.path = str(path)
    figure = plot_recording(rec, path.with_suffix(".png"), f"{path.name}: truth {plant.model.spec}")
    return {
        "recording": str(path),
        "figure": figure,
        "samples": len(rec),
        "seconds": args.seconds,
        "truth": plant.model.spec,
        "params": {k: float(v) for k, v in plant.params.items()},
        "tracking_rms": tracking_rms(rec),
    }


def render(r: dict) -> str:
    track = ", ".join(f"{x:.4f}" for x in r["tracking_rms"])
    return (
        f"wrote {r['samples']} samples ({r['seconds']:g} s) of truth {r['truth']}\n"
        f"  tracking error RMS per joint: {track}\n  recording: {r['recording']}\n  figure:    {r['figure']}"
    )
