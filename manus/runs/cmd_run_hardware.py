"""`manus run-hardware`: the real-time loop against a rig (or `manus emulate`) from the command line."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from manus.runs.args import add_json, output_file
from manus.runs.progress import note

NAME = "run-hardware"
HELP = "run an adaptive controller and velocity estimator against a rig at its rate, with safety and a recording"


def add_arguments(p) -> None:
    p.add_argument("--device", required=True, metavar="URL", help="the rig, e.g. udp://127.0.0.1:5555")
    p.add_argument("--controller", default="slotine-li", help="impedance, slotine-li or slotine-li-composite")
    p.add_argument("--estimator", default="kalman_cv", help="velocity estimator (see `manus estimators`)")
    p.add_argument("--model", default="rigid,viscous,coulomb", help="the controller's model (adaptive ones)")
    p.add_argument(
        "--robot",
        metavar="FILE.urdf",
        default=None,
        help="the rig is this serial robot (its joints the device's; adaptive controllers adapt in "
        "pseudo-inertia coordinates, manus.plants.pseudo_inertia)",
    )
    p.add_argument(
        "--structure",
        choices=("manus2", "axis"),
        default=None,
        help="default: manus2 for a 2-joint device, axis otherwise",
    )
    p.add_argument("--reference", choices=("benign", "complex", "hold", "multisine"), default="benign")
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument(
        "--record",
        type=output_file(".csv"),
        default=None,
        metavar="FILE",
        help="the recording (.csv), written as the run goes",
    )
    p.add_argument(
        "--rig",
        type=Path,
        default=None,
        metavar="FILE.toml",
        help="the rig's limits: a TOML file with a [limits] table (torque, velocity, span or low/high, jump, "
        "stall_seconds, stall_speed; docs/hardware.md); default: the thesis arm's (7 N·m, 4 rad/s, the start ± 1 rad)",
    )
    p.add_argument(
        "--torque-limit",
        type=float,
        default=None,
        help="|τ| limit [N·m], instead of the rig file's (never more than the device's D/A reaches)",
    )
    p.add_argument("--torque", action="store_true", help="send torques (default: D/A volts)")
    p.add_argument(
        "--realtime",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the loop under SCHED_FIFO with memory locked, waiting by blocking, where allowed (root or "
        "CAP_SYS_NICE; else an ordinary process, said); --no-realtime: an ordinary process that spins "
        "near each sample (default: real-time)",
    )
    p.add_argument(
        "--watchdog-ms",
        type=float,
        default=20.0,
        help="no sample for this long: stop (default 20: this 2-vCPU VM stalls a process for up to ~20 ms a few "
        "times a minute, measured)",
    )
    add_json(p)


def run(args) -> dict:
    from manus.plants.device import open_device
    from manus.plants.errors import ManusError
    from manus.plants.hardware import realtime_jax, report, run_loop

    realtime_jax()  # before JAX computes anything
    from manus.adaptive.controllers import compiled_tick

    if not args.seconds > 0:
        raise ManusError("--seconds must be positive")
    if not args.watchdog_ms > 0:
        raise ManusError("--watchdog-ms must be positive")
    import dataclasses

    from manus.plants.limits import Limits

    limits = Limits.read(args.rig) if args.rig is not None else Limits()
    if args.torque_limit is not None:
        try:
            limits = dataclasses.replace(limits, torque=args.torque_limit)
        except ManusError as e:
            raise ManusError(f"--torque-limit: {e}") from None
    with open_device(args.device) as device:
        info = device.connect()  # what the device is; the run opens its own session below
        device.stop()
        note(
            f"{args.device}: {info.n_joints} joints at {info.rate_hz:g} Hz, {info.counts_per_rev:g} counts/rev; "
            f"compiling {args.controller} + {args.estimator} ..."
        )
        stepper = compiled_tick(
            info,
            args.controller,
            args.estimator,
            args.model,
            args.structure,
            args.reference,
            limits,
            args.robot,
        )
        meta = {
            "controller": args.controller,
            "estimator": args.estimator,
            "model": args.model,
            "reference": args.reference,
            "device": args.device,
            "structure": "urdf" if args.robot else (args.structure or ("manus2" if info.n_joints == 2 else "axis")),
        }
        if args.robot:
            meta["robot"] = str(Path(args.robot).absolute())
        lim = stepper.limits
        note(f"running {args.seconds:g} s (|τ| ≤ {lim.torque:g} N·m, |q̇| ≤ {lim.velocity:g} rad/s) ...")
        result = run_loop(
            device,
            stepper,
            args.seconds,
            args.record,
            watchdog=args.watchdog_ms / 1e3,
            volts=not args.torque,
            meta=meta,
            realtime=args.realtime,
        ).as_dict()
    if result["stopped_by"] == "limit" and args.rig is None:
        result["reason"] += " (the thesis arm's default limits: a rig file, --rig FILE.toml, states another rig's)"
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
