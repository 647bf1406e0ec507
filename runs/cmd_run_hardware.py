"""`manus run-hardware`: the real-time loop against a rig (or `manus emulate`) from the command line."""

from __future__ import annotations

import json
from pathlib import Path

from manus.runs.common import note

NAME = "run-hardware"
HELP = "run an adaptive controller and velocity estimator against a rig at its rate, with safety and a recording"


def add_arguments(p) -> None:
    p.add_argument("--device", required=True, metavar="URL", help="the rig, e.g. udp://127.0.0.1:5555")
    p.add_argument("--controller", default="slotine-li", help="impedance, slotine-li or slotine-li-composite")
    p.add_argument("--estimator", default="kalman_cv", help="velocity estimator (see `manus estimators`)")
    p.add_argument("--model", default="rigid,viscous,coulomb", help="the controller's model (adaptive ones)")
    p.add_argument("--robot", metavar="FILE.urdf", default=None,
                   help="the rig is this serial robot (its joints the device's; adaptive controllers adapt in "
                        "pseudo-inertia coordinates, manus.plants.serial_pseudo)")
    p.add_argument("--structure", choices=("manus2", "axis"), default=None,
                   help="default: manus2 for a 2-joint device, axis otherwise")
    p.add_argument("--reference", choices=("benign", "complex", "hold", "multisine"), default="benign")
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--record", type=Path, default=None, metavar="FILE", help="the recording (.csv), written as the run goes")
    p.add_argument("--torque-limit", type=float, default=None, help="|τ| limit [N·m] (default: the device's)")
    p.add_argument("--torque", action="store_true", help="send torques (default: D/A volts)")
    p.add_argument("--watchdog-ms", type=float, default=20.0, help="no sample for this long: stop (default 20: this 2-vCPU VM stalls a process for up to ~20 ms a few times a minute, measured)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout and nothing else")


def reference_for(name: str, structure: str, n: int):
    import numpy as np

    from manus.plants.errors import ManusError
    from manus.plants.references import CENTRE, Benign, Complex, Hold, MultiSine

    centre = np.array(CENTRE) if structure == "manus2" else np.zeros(n)
    if name in ("benign", "complex") and structure != "manus2":
        raise ManusError(f"the {name} trajectory is the thesis's for the manus2 arm (try --reference multisine)")
    return {"benign": Benign, "complex": Complex, "hold": lambda: Hold(centre),
            "multisine": lambda: MultiSine(centre)}[name]()


def build_stepper(info, controller: str, estimator: str, model_spec: str, structure: str | None, reference: str,
                  torque_limit: float | None = None, robot: str | None = None):
    """The compiled tick of `controller` + `estimator` for the device described by `info`, warmed up."""
    from manus.adaptive.controllers import make_controller
    from manus.plants import Model, structure_named
    from manus.plants.errors import ManusError
    from manus.plants.hardware import CompiledTick

    n = info.n_joints
    if robot is not None:
        from manus.plants.serial import Serial

        chain = Serial.from_urdf(robot)
        if chain.n_joints != n:
            raise ManusError(f"the device has {n} joint(s); the robot {robot} has {chain.n_joints} "
                             f"({', '.join(chain.joint_names)})")
        shape, structure = chain.pseudo(), "urdf"
    else:
        structure = structure or ("manus2" if n == 2 else "axis")
        if structure == "manus2" and n != 2:
            raise ManusError(f"the device has {n} joint(s); manus2 has 2 (use --structure axis)")
        shape = structure_named(structure, n)
    dt = 1.0 / info.rate_hz
    model = Model(shape, model_spec)
    limit = info.torque_limit if torque_limit is None else min(torque_limit, info.torque_limit)
    if not limit > 0:
        raise ManusError(f"--torque-limit must be positive, got {torque_limit}")
    gains = {} if controller == "impedance" else {"limit": limit}
    c = make_controller(controller, model, dt, estimator=estimator, **gains)
    tick = CompiledTick(c, reference_for(reference, structure, n), dt, info.counts_per_rev, n, limit)
    tick.warm_up()
    return tick


def run(args) -> dict:
    from manus.plants.device import open_device
    from manus.plants.errors import ManusError
    from manus.plants.hardware import realtime_jax, report, run_loop

    realtime_jax()
    if not args.seconds > 0:
        raise ManusError("--seconds must be positive")
    if not args.watchdog_ms > 0:
        raise ManusError("--watchdog-ms must be positive")
    if args.record is not None and args.record.suffix.lower() != ".csv":
        raise ManusError(f"--record {args.record}: the loop streams a .csv recording")
    with open_device(args.device) as device:
        info = device.connect()  # what the device is; the run opens its own session below
        device.stop()
        note(f"{args.device}: {info.n_joints} joints at {info.rate_hz:g} Hz, {info.counts_per_rev:g} counts/rev; "
             f"compiling {args.controller} + {args.estimator} ...")
        stepper = build_stepper(info, args.controller, args.estimator, args.model, args.structure, args.reference,
                                args.torque_limit, args.robot)
        meta = {"controller": args.controller, "estimator": args.estimator, "model": args.model,
                "reference": args.reference, "device": args.device,
                "structure": "urdf" if args.robot else (args.structure or ("manus2" if info.n_joints == 2 else "axis"))}
        if args.robot:
            meta["robot"] = str(Path(args.robot).absolute())
        note(f"running {args.seconds:g} s ...")
        result = run_loop(device, stepper, args.seconds, args.record, watchdog=args.watchdog_ms / 1e3,
                          torque_limit=args.torque_limit, volts=not args.torque, meta=meta).as_dict()
    if args.record is not None:
        summary = args.record.with_suffix(".stats.json")
        summary.write_text(json.dumps(result, indent=1) + "\n")
        result["stats"] = str(summary)
    if args.json:
        note(report(result))  # stdout holds the JSON only
    return result


def render(r: dict) -> str:
    from manus.plants.hardware import report

    return report(r)
