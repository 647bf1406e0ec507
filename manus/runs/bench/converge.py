"""`manus bench converge`: parameter-convergence trials per second, the batch of N trials (4 s of
the complex trajectory each, one vmapped `lax.scan`, and the statistics `manus converge`
reports: `run_trials` then `summarize`) beside the same trials one by one in a Python loop,
measured in the same run.

Two one-by-one baselines, each timed on a few trials and extrapolated to N (said so in the
result): a Python loop over trials, each one `lax.scan` jitted once (`manus.adaptive.slotine_li.trial`:
the batch's ticks, statistics and records for one trial, unbatched); and a Python loop over
ticks, the plant and controller steps jitted once and called per tick (how the hardware loop
runs a controller). Compilation is timed apart and left out of every rate.

Beside them, the ceiling: `manus bench sim`'s bare-plant batch (the thesis plant under impedance
control, `simulate_batch` split over the devices) measured in the same run with the same number
of trials and length, recording every tick as the convergence batch does and every 100th as
`manus bench sim`'s headline does. The batch is timed best of `--repeats` (wall and CPU time of
all threads).

On a machine shared with other work the wall-clock rates move with the load (printed beside
them); the CPU time per trial-step moves much less. So the result also gives the batch's speedup
in CPU time (the scan loop's CPU per step over the batch's CPU per trial-step: the work saved,
whatever the load) and what the batch would reach with the devices' cores to itself (trial-steps
per CPU-second times the number of devices: the wall rate of an idle machine, less whatever
does not run in parallel).
"""

from __future__ import annotations

import os
import time

HELP = "convergence trials per second: the vmapped batch beside one-by-one Python loops"


def add_arguments(p) -> None:
    p.add_argument("--trials", type=int, default=200)
    p.add_argument("--seconds", type=float, default=4.0)
    p.add_argument("--model", default="rigid,viscous,coulomb", metavar="EFFECTS")
    p.add_argument("--law", choices=("gradient", "composite"), default="gradient")
    p.add_argument("--sample", type=int, default=3, help="one-by-one trials timed (then extrapolated)")
    p.add_argument("--tick-sample", type=float, default=0.5, help="seconds of one trial timed tick by tick")
    p.add_argument("--repeats", type=int, default=2, help="the batches: best of this many timed runs")


def _timed(f, *args):
    import jax

    start = time.perf_counter()
    out = jax.block_until_ready(f(*args))
    return time.perf_counter() - start, out


def _timed_cpu(f, *args) -> tuple[float, float]:
    """(wall, CPU of all threads) of one call [s]."""
    import jax

    t0, c0 = time.perf_counter(), time.process_time()
    jax.block_until_ready(f(*args))
    return time.perf_counter() - t0, time.process_time() - c0


def _best(f, repeats: int) -> tuple[float, float]:
    """Best (wall, CPU of all threads) of `repeats` calls [s], after the caller's warm-up."""
    import jax

    best = (float("inf"), float("inf"))
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        jax.block_until_ready(f())
        best = min(best, (time.perf_counter() - t0, time.process_time() - c0))
    return best


def bare_plant(trials: int, seconds: float, repeats: int) -> dict:
    """`manus bench sim`'s batch (the same plant, controllers and reference) at this size."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from manus.adaptive.impedance import Impedance
    from manus.plants import Manus2, Model, Simulator
    from manus.plants.closed_loop import simulate_batch
    from manus.plants.references import Complex
    from manus.runs.bench.sim import PLANT

    plant, reference = Simulator(Model(Manus2(), PLANT)), Complex()
    controllers = eqx.filter_vmap(lambda k: Impedance(k, 1.0))(jnp.linspace(10.0, 60.0, trials))
    keys = jax.random.split(jax.random.PRNGKey(0), trials)
    out = {}
    for every in (1, 100):

        def batch(every=every):
            return simulate_batch(plant, controllers, reference, seconds, keys, batched=("controller",), every=every)

        batch()  # compile
        wall, cpu = _best(batch, repeats)
        out[every] = trials * int(round(seconds / plant.dt)) / wall
        out[f"cpu{every}"] = cpu / (trials * int(round(seconds / plant.dt))) * 1e9
    return {"plant": PLANT, "record_every_tick": out[1], "record_every_100": out[100], "cpu_ns_every_tick": out["cpu1"]}


def run(args) -> dict:
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from manus.adaptive.slotine_li import SlotineLi, trial
    from manus.experiments.convergence import EVERY, RECORD, controller_for, run_trials, summarize
    from manus.plants import Model, Simulator
    from manus.plants.errors import ManusError
    from manus.plants.references import Complex
    from manus.plants.structures import Manus2
    from manus.runs.progress import note

    if args.trials < 1 or args.sample < 1 or args.repeats < 1 or args.seconds <= 0 or args.tick_sample <= 0:
        raise ManusError("need --trials, --sample, --repeats >= 1 and positive --seconds, --tick-sample")
    plant = Simulator(Model(Manus2(), "rigid,viscous,coulomb"), torque_noise=0.005)
    model = Model(Manus2(), args.model)
    controller = controller_for(plant, model, args.law, "kalman_cv")
    assert isinstance(controller, SlotineLi)  # controller_for makes a Slotine–Li law
    reference = Complex()
    steps = EVERY * max(1, int(round(args.seconds / plant.dt / EVERY)))
    seconds = steps * plant.dt

    note(
        f"batch of {args.trials} trials ({seconds:g} s each) on {len(jax.devices())} device(s): compiling, "
        f"then best of {args.repeats} ..."
    )
    first, _ = _timed(lambda: summarize(run_trials(plant, controller, reference, args.trials, seconds)))
    batch, batch_cpu = _best(
        lambda: summarize(run_trials(plant, controller, reference, args.trials, seconds, seed=1)), args.repeats
    )

    note(f"one by one, a scan per trial: {args.sample} trial(s) ...")
    truth = jnp.asarray([float(plant.params.get(k, 0.0)) for k in controller.names])
    one = eqx.filter_jit(lambda c, k: trial(plant, c, reference, steps, k, truth, EVERY, RECORD))
    keys = jax.random.split(jax.random.PRNGKey(0), args.sample + 1)
    compile_one, _ = _timed(one, controller, keys[0])
    scan_s, scan_cpu = min(_timed_cpu(one, controller, k) for k in keys[1:])

    ticks = max(1, int(round(args.tick_sample / plant.dt)))
    note(f"one by one, tick by tick: {ticks} ticks ...")
    plant_step, ctrl_step = eqx.filter_jit(plant.step), eqx.filter_jit(controller.step)
    pstate, q = plant.reset(keys[0], q0=reference(0.0).q)
    cstate = controller.init(q)
    refs = [reference(k * plant.dt) for k in range(ticks + 1)]
    cstate, u = ctrl_step(cstate, q, refs[0])  # compile both steps
    pstate, q = plant_step(pstate, u)
    start = time.perf_counter()
    for k in range(1, ticks + 1):
        cstate, u = ctrl_step(cstate, q, refs[k])
        pstate, q = plant_step(pstate, u)
    jax.block_until_ready(q)
    tick_s = (time.perf_counter() - start) / ticks * steps  # one trial, extrapolated

    note(f"the bare plant ({args.trials} trials, manus bench sim's batch) ...")
    bare = bare_plant(args.trials, seconds, args.repeats)

    devices = len(jax.devices())
    batch_cpu_ns = batch_cpu / (args.trials * steps) * 1e9
    figures = {
        "batch_trials_per_s": args.trials / batch,
        "batch_trial_steps_per_s": args.trials * steps / batch,
        "batch_cpu_ns_per_trial_step": batch_cpu_ns,
        "batch_trial_steps_per_s_idle": devices * 1e9 / batch_cpu_ns,
        "scan_loop_trial_steps_per_s": steps / scan_s,
        "scan_loop_cpu_ns_per_step": scan_cpu / steps * 1e9,
        "bare_plant_batch_trial_steps_per_s": bare["record_every_tick"],
        "bare_plant_batch_cpu_ns_per_trial_step": bare["cpu_ns_every_tick"],
        "bare_plant_batch_every_100_trial_steps_per_s": bare["record_every_100"],
        "scan_loop_trials_per_s": 1 / scan_s,
        "tick_loop_trials_per_s": 1 / tick_s,
        "tick_loop_us_per_tick": tick_s / steps * 1e6,
        "batch_compile_s": first - batch,
        "scan_compile_s": compile_one - scan_s,
    }
    return {
        "figures": figures,
        "speedup": scan_s * args.trials / batch,
        "speedup_vs_tick_loop": tick_s * args.trials / batch,
        "speedup_cpu": scan_cpu / steps * 1e9 / batch_cpu_ns,
        "load_average": os.getloadavg()[0],
        "cores": os.cpu_count(),
        "of_bare_plant": args.trials * steps / batch / bare["record_every_tick"],
        "bare_plant": bare["plant"],
        "trials": args.trials,
        "seconds": seconds,
        "model": model.spec,
        "law": args.law,
        "devices": devices,
        "note": (
            f"one-by-one rates timed on {args.sample} scanned trial(s) and {ticks} ticks of one trial, "
            f"extrapolated to {args.trials} trials of {seconds:g} s; compilation excluded"
        ),
    }


def render(r: dict) -> str:
    f = r["figures"]
    return "\n".join(
        [
            f"benchmark converge: {r['trials']} trials of {r['seconds']:g} s, model {r['model']}, {r['law']} law",
            f"  batch (vmapped scan, {r['devices']} device(s)): {f['batch_trials_per_s']:8.2f} trials/s  "
            f"({f['batch_trial_steps_per_s']:.3g} trial-steps/s, {f['batch_cpu_ns_per_trial_step']:.0f} ns CPU per "
            f"trial-step; compile {f['batch_compile_s']:.1f} s)",
            f"  one by one, scan per trial:  {f['scan_loop_trials_per_s']:8.2f} trials/s  "
            f"({f['scan_loop_trial_steps_per_s']:.3g} steps/s; compile {f['scan_compile_s']:.1f} s)",
            f"  one by one, tick by tick:    {f['tick_loop_trials_per_s']:8.3f} trials/s  "
            f"({f['tick_loop_us_per_tick']:.0f} µs per tick)",
            f"  speedup of the batch: {r['speedup']:.3g}x over the scan loop, {r['speedup_vs_tick_loop']:.3g}x over "
            "the tick loop",
            f"  the bare plant ({r['bare_plant']} under impedance control, manus bench sim's batch, same size): "
            f"{f['bare_plant_batch_trial_steps_per_s']:.3g} trial-steps/s recording every tick "
            f"({f['bare_plant_batch_cpu_ns_per_trial_step']:.0f} ns CPU per trial-step), "
            f"{f['bare_plant_batch_every_100_trial_steps_per_s']:.3g} every 100th; the convergence batch runs at "
            f"{100 * r['of_bare_plant']:.0f} % of the first",
            f"  in CPU time: the batch {f['batch_cpu_ns_per_trial_step']:.0f} ns per trial-step, the scan loop "
            f"{f['scan_loop_cpu_ns_per_step']:.0f} ns per step: {r['speedup_cpu']:.3g}x less work; with "
            f"{r['devices']} core(s) to itself the batch would run {f['batch_trial_steps_per_s_idle']:.3g} "
            "trial-steps/s "
            f"(1-min load average {r['load_average']:.1f} on {r['cores']} cores at the end, this run included)",
            f"  ({r['note']})",
        ]
    )
