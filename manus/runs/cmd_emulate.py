"""`manus emulate --port P`: play the rig (the JAX simulator in real time behind the device protocol)."""

from __future__ import annotations

import math
import signal
from pathlib import Path

from manus.runs.args import add_json, add_plant_options, build_plant
from manus.runs.progress import note

NAME = "emulate"
HELP = "play the rig: the simulator in real time behind the UDP device protocol (for run-hardware)"


def add_arguments(p) -> None:
    p.add_argument("--port", type=int, required=True, help="UDP port to listen on (0: any free port, printed)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument(
        "--watchdog-ms",
        type=float,
        default=20.0,
        help="no valid command for this long: zero torque for the rest of the session (default 20: this 2-vCPU VM "
        "stalls a process for up to ~20 ms a few times a minute, measured)",
    )
    p.add_argument("--seconds", type=float, default=None, help="exit after this long (default: run until Ctrl-C)")
    p.add_argument("--drop", type=float, default=0.0, help="fault injection: lose this fraction of packets each way")
    p.add_argument("--garbage", type=float, default=0.0, help="fault injection: send this fraction of junk datagrams")
    p.add_argument(
        "--log",
        type=Path,
        default=None,
        metavar="FILE",
        help="write what the device did (positions, applied torques, flags) as a recording",
    )
    p.add_argument(
        "--spin-ms",
        type=float,
        default=2.0,
        help="busy-wait this long before each tick instead of sleeping (a sleeping vCPU wakes late; default 2)",
    )
    p.add_argument(
        "--realtime",
        action="store_true",
        help="serve under SCHED_FIFO with memory locked, waiting by blocking (where allowed: root or CAP_SYS_NICE)",
    )
    p.add_argument("--seed", type=int, default=0, help="seed of the fault injection")
    p.add_argument(
        "--fault",
        choices=("runaway", "stall", "jump", "bad-info", "late"),
        default=None,
        help="fault injection: a rig gone wrong from --fault-at seconds after each session starts to its end, "
        "whatever is commanded. runaway: joint 1's driver delivers the D/A's full positive torque; stall: the arm "
        "is blocked (positions frozen, velocities zero); jump: joint 1's encoder reports 2**31-1 counts; bad-info: "
        "the INFO packet says volt_limit=inf (from the session's start); late: each sample is sent 3 ms after it "
        "was taken (stamped when taken), so the host's commands miss their deadlines",
    )
    p.add_argument(
        "--fault-at",
        type=float,
        default=1.0,
        metavar="SECONDS",
        help="when --fault starts, in seconds after each session starts (HELLO) (default 1)",
    )
    add_json(p, "print one JSON object on stdout at exit")
    p.add_argument(
        "--torque-limit",
        type=float,
        default=100.0,
        help="with --robot: the largest torque its (ideal, 24-bit) D/A reaches [N·m] (default 100)",
    )
    add_plant_options(p, robot=True)


def run(args) -> dict:
    from manus.plants.emulator import Emulator
    from manus.plants.errors import ManusError
    from manus.plants.hardware import realtime_jax

    realtime_jax()

    if not args.watchdog_ms > 0:
        raise ManusError("--watchdog-ms must be positive")
    if args.counts <= 0:
        raise ManusError("--counts must be positive: a rig's encoder has a resolution")
    if args.robot and not args.torque_limit > 0:
        raise ManusError("--torque-limit must be positive")
    if not (math.isfinite(args.fault_at) and args.fault_at >= 0):
        raise ManusError(f"--fault-at {args.fault_at:g}: seconds after the session starts (finite, >= 0)")
    plant = build_plant(args, robot_torque_limit=args.torque_limit if args.robot else None)
    emu = Emulator(
        plant,
        args.port,
        args.host,
        watchdog=args.watchdog_ms / 1e3,
        drop=args.drop,
        garbage=args.garbage,
        log=args.log,
        seed=args.seed,
        spin=args.spin_ms / 1e3,
        fault=args.fault,
        fault_at=args.fault_at,
        realtime=args.realtime,
    )
    fault = f", fault {args.fault} at {args.fault_at:g} s into each session" if args.fault else ""
    note(
        f"emulating {plant.model.spec} ({plant.model.n_joints} joints, {plant.rate_hz:g} Hz) "
        f"on udp://{args.host}:{emu.port}{fault}",
    )
    signal.signal(signal.SIGTERM, _interrupt)  # a terminate closes the log like Ctrl-C
    try:
        stats = emu.serve(args.seconds)
    except KeyboardInterrupt:
        emu.close()
        stats = {"refused": dict(emu.refused), **dict(emu.stats)}
    return {"port": emu.port, "truth": plant.model.spec, "fault": args.fault, "sessions": emu.session, **stats}


def _interrupt(*_):
    raise KeyboardInterrupt


def render(r: dict) -> str:
    refused = ", ".join(f"{k} {v}" for k, v in sorted(r["refused"].items())) or "none"
    fault = f", fault {r['fault']}" if r.get("fault") else ""
    return (
        f"emulator on port {r['port']} ({r['truth']}{fault}): {r['sessions']} session(s), {r.get('ticks', 0)} ticks, "
        f"{r.get('late', 0)} late commands, {r.get('watchdog_trips', 0)} watchdog trips; refused: {refused}"
    )
