"""`manus bench stability`: step tests of the (b_c, k) grid per second — the thesis's 5 s step
test on the compliant, quantized, delayed axis (5000 control ticks, 10 physics sub-steps each) —
all points in one vmapped call against a plain Python loop calling the same jitted single
trial point after point, in one run."""

from __future__ import annotations

import time

import numpy as np

from manus.runs.bench import best_time

HELP = "step tests per second over the (b_c, k) grid: one vmapped call vs a Python loop over points"


def add_arguments(p) -> None:
    p.add_argument("--points", type=int, default=2048, help="grid points in the vmapped call")
    p.add_argument("--loop-points", type=int, default=24, help="points run one by one in the baseline")
    p.add_argument("--repeats", type=int, default=3, help="best of this many timed runs")


def run(args) -> dict:
    import jax

    from manus.experiments.stability import sweep
    from manus.experiments.stability.steptest import StepTest
    from manus.plants.errors import ManusError
    from manus.runs.progress import note

    if args.points < 1 or args.loop_points < 1 or args.repeats < 1:
        raise ManusError("--points, --loop-points and --repeats must be positive")
    test = StepTest()
    rng = np.random.default_rng(0)
    b_c, k = rng.uniform(0.0, 35.0, args.points), rng.uniform(100.0, 8000.0, args.points)

    note(f"vmapped: {args.points} step tests per call on {len(jax.devices())} device(s) ...")
    t0 = time.perf_counter()
    sweep.local(test, k, b_c, bucketed=False)
    compile_batch = time.perf_counter() - t0
    batch = best_time(lambda: sweep.local(test, k, b_c, bucketed=False), args.repeats)

    note(f"loop: {args.loop_points} step tests one by one ...")
    one = jax.jit(test.metrics)
    t0 = time.perf_counter()
    jax.block_until_ready(one(k[0], b_c[0]))
    compile_one = time.perf_counter() - t0
    loop = best_time(lambda: [jax.block_until_ready(one(k[i], b_c[i])) for i in range(args.loop_points)], args.repeats)

    vmapped, looped = args.points / batch, args.loop_points / loop
    substeps = test.ticks * round(test.physics_hz / test.rate_hz)
    return {
        "figures": {
            "vmapped_points_per_s": vmapped,
            "loop_points_per_s": looped,
            "vmapped_substeps_per_s": vmapped * substeps,
            "loop_substeps_per_s": looped * substeps,
            "compile_vmapped_s": compile_batch,
            "compile_single_s": compile_one,
        },
        "speedup": vmapped / looped,
        "points": args.points,
        "loop_points": args.loop_points,
        "ticks_per_point": test.ticks,
        "substeps_per_tick": round(test.physics_hz / test.rate_hz),
        "devices": len(jax.devices()),
    }


def render(r: dict) -> str:
    f = r["figures"]
    return (
        f"stability step tests ({r['ticks_per_point']} ticks x {r['substeps_per_tick']} sub-steps each), "
        f"{r['devices']} device(s)\n"
        f"  vmapped ({r['points']} points per call): {f['vmapped_points_per_s']:.0f} points/s "
        f"({f['vmapped_substeps_per_s']:.3g} sub-steps/s; compile {f['compile_vmapped_s']:.1f} s)\n"
        f"  Python loop over points ({r['loop_points']}): {f['loop_points_per_s']:.1f} points/s "
        f"({f['loop_substeps_per_s']:.3g} sub-steps/s; compile {f['compile_single_s']:.1f} s)\n"
        f"  speedup {r['speedup']:.0f}x"
    )
