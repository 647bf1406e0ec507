"""`manus simulate`: simulate a plant under closed-loop control and write the recording."""

from __future__ import annotations

from pathlib import Path

from manus.runs.common import note
from manus.runs.plants_cli import add_plant_options, build_plant

NAME = "simulate"
SERIAL_PD_HZ = 5.0  # a serial robot's default PD bandwidth around its computed torque
HELP = ("simulate the arm, axes or a serial robot (--robot FILE.urdf) under control and write a recording with "
        "true velocities")


def add_arguments(p) -> None:
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--reference", choices=("multisine", "benign", "complex", "hold"), default="multisine")
    p.add_argument("--amplitude", type=float, default=0.15, help="multi-sine amplitude per joint [rad or m]")
    p.add_argument("--seed", type=int, default=0, help="multi-sine phases and plant noise")
    p.add_argument("--stiffness", type=float, default=None,
                   help="impedance controller K [N·m/rad] (default 30; a serial robot's PD around its computed "
                        "torque: a 5 Hz loop on each joint's inertia)")
    p.add_argument("--damping", type=float, default=None,
                   help="impedance controller B [N·m·s/rad] (default 1; a serial robot's: critically damped)")
    p.add_argument("--out", type=Path, default=Path("runs/out/simulated.csv"), metavar="FILE",
                   help="the recording to write (.csv or .npz); a figure goes beside it (.png)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout and nothing else")
    add_plant_options(p, robot=True)


def run(args) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    from manus.adaptive.impedance import Impedance
    from manus.plants import recording
    from manus.plants.closed_loop import simulate
    from manus.plants.errors import ManusError
    from manus.plants.references import Benign, Complex, Hold, MultiSine
    from manus.plants.simulator import workspace_centre
    from manus.runs.plots import plot_recording, rms

    if args.seconds <= 0:
        raise ManusError("--seconds must be positive")
    plant = build_plant(args)
    n = plant.model.n_joints
    centre = np.asarray(workspace_centre(plant.model))
    if args.reference in ("benign", "complex") and (args.structure != "manus2" or getattr(args, "robot", None)):
        raise ManusError(f"the {args.reference} trajectory is the thesis's for the manus2 arm")
    reference = {"multisine": lambda: MultiSine(centre, args.amplitude, seed=args.seed),
                 "benign": Benign, "complex": Complex, "hold": lambda: Hold(centre)}[args.reference]()
    serial = getattr(args, "robot", None)
    if serial:  # a robot arm under gravity: the URDF's computed torque along the reference, plus a PD
        from manus.plants.serial_sim import Feedforward

        chain = plant.model.structure
        # by default each joint's PD is a 5 Hz, critically damped loop on its own inertia (the URDF's at the start)
        h = np.diag(np.asarray(chain.mass_matrix(jnp.asarray(centre), jnp.asarray(chain.defaults))))
        w = 2 * np.pi * SERIAL_PD_HZ
        k = h * w**2 if args.stiffness is None else np.full(n, args.stiffness)
        b = 2 * h * w if args.damping is None else np.full(n, args.damping)
        controller = Feedforward(chain, plant.dt, stiffness=k, damping=b)
        how = (f"computed torque (the URDF's parameters) + PD K={', '.join(f'{x:.3g}' for x in k)} "
               f"B={', '.join(f'{x:.3g}' for x in b)}")
    else:
        k, b = (30.0 if args.stiffness is None else args.stiffness), (1.0 if args.damping is None else args.damping)
        controller = Impedance(k, b, n_joints=n, limit=plant.actuator.limit)
        how = f"impedance K={k:g} B={b:g}"
    note(f"simulating {args.seconds:g} s of {plant.model.spec} at {plant.rate_hz:g} Hz ...")
    traj = simulate(plant, controller, reference, args.seconds, key=jax.random.PRNGKey(args.seed),
                    progress=args.seconds > 5)
    rec = recording.from_trajectory(traj, plant.rate_hz, plant.model.structure,
                                    args.counts if args.counts > 0 else None,
                                    {"truth": plant.model.spec, "reference": args.reference, "controller": how})
    path = recording.write(rec, args.out)
    rec.path = str(path)
    figure = plot_recording(rec, path.with_suffix(".png"), f"{path.name}: truth {plant.model.spec}")
    return {"recording": str(path), "figure": figure, "samples": len(rec), "seconds": args.seconds,
            "truth": plant.model.spec, "params": {k: float(v) for k, v in plant.params.items()},
            "tracking_rms": rms(rec.q - np.stack([rec.extra[f"qref{i + 1}"] for i in range(n)], 1)).tolist()}


def render(r: dict) -> str:
    track = ", ".join(f"{x:.4f}" for x in r["tracking_rms"])
    return (f"wrote {r['samples']} samples ({r['seconds']:g} s) of truth {r['truth']}\n"
            f"  tracking error RMS per joint: {track}\n  recording: {r['recording']}\n  figure:    {r['figure']}")
