"""`manus bench sim`: closed-loop simulation of the MANUS-2 arm in control steps per second.

The thesis plant (`rigid,viscous,coulomb,delay`, the actuator chain and the 131072 counts/rev
encoder: `manus.plants.Simulator`'s defaults) under impedance control (`manus.adaptive.impedance.Impedance`,
the filtered first-difference velocity) following the complex trajectory (App. C), 1 kHz
control with 10 physics sub-steps, timed three ways in one run (best of `--repeats`, compile
excluded):

- one trial (`simulate`), steps/s;
- a batch of trials with different gains (`simulate_batch`, split over the devices), trial-steps/s:
  recording every `--every`-th tick (the headline), and recording every tick (1000 trials × 5 s
  is a 440 MB record, whose writing and copying weigh on this figure);
- the baseline: a plain numpy loop of the same model (same integrator, friction step, actuator,
  delay, encoder and controller), steps/s, on a shorter run; its positions are compared with the
  JAX simulation's (`agreement_counts`, in encoder counts).
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

HELP = "closed-loop simulation of the arm: one trial, a batch of trials, and a numpy loop of the same model"
PLANT = "rigid,viscous,coulomb,delay"


def add_arguments(p) -> None:
    p.add_argument("--trials", type=int, default=1000, help="trials in the batch")
    p.add_argument("--seconds", type=float, default=5.0, help="simulated time per trial [s]")
    p.add_argument("--numpy-seconds", type=float, default=0.5, help="simulated time of the numpy baseline [s]")
    p.add_argument("--every", type=int, default=100, help="the batch records every N-th tick (default: 10 Hz)")
    p.add_argument("--float32", action="store_true", help="run the JAX simulations in float32 (numpy stays float64)")
    p.add_argument("--repeats", type=int, default=3, help="best of this many timed runs")


def _best(fn, repeats: int) -> tuple[float, float]:
    """Best wall time of `repeats` calls after a warm-up one, and the process CPU time (all
    threads) of that call [s]."""
    fn()  # compile and warm up
    best = (math.inf, math.inf)
    for _ in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        best = min(best, (time.perf_counter() - t0, time.process_time() - c0))
    return best


def numpy_closed_loop(seconds: float, stiffness=30.0, damping=1.0) -> np.ndarray:
    """The benchmark's closed loop as a plain numpy loop; returns the measured positions (T, 2).

    The same equations as `manus.plants.Simulator` with the thesis plant and
    `manus.adaptive.impedance.Impedance`, written out for this one model: absolute-angle arm
    (eqs. C.1–C.2), viscous and Coulomb friction, Störmer–Verlet sub-steps with the implicit
    (Moreau) friction step, 12-bit D/A, a 1 ms delay (one period), 131072 counts/rev encoder.
    """
    a1, a2, a3 = 0.349, 0.241, 0.246
    b, fc = np.array([0.222, 0.181]), np.array([0.099, 0.139])
    period, substeps = 1e-3, 10
    h = period / substeps
    torque_per_volt, lsb = 0.6 * 3.7, 20 / 4096
    count = 2 * np.pi / 131072
    lam = 188.5 * period
    alpha, beta = (2 - lam) / (2 + lam), 2 * 188.5 / (2 + lam)
    centre = np.array([0.464, 2.409])

    def inertia(q):
        c = np.cos(q[1] - q[0])
        return np.array([[a1, a2 * c], [a2 * c, a3]])

    def accel(q, v, tau):
        s = np.sin(q[1] - q[0])
        coriolis = np.array([-a2 * s * v[1] ** 2, a2 * s * v[0] ** 2])
        return np.linalg.solve(inertia(q), tau - coriolis - b * v)

    def friction(H, v, h):  # argmin ½ fᵀ(h H⁻¹)f − fᵀv over −Fc ≤ f ≤ Fc
        u = v * (H[0, 0] * H[1, 1] - H[0, 1] ** 2) / h
        edges = [(u[0] + H[0, 1] * bound) / H[1, 1] for bound in (-fc[1], fc[1])]
        g = (H[0, 0] * v[0] + H[0, 1] * v[1]) / h
        f1 = np.clip(sorted([*edges, g])[1], -fc[0], fc[0])  # the median: see plants.structures.Sym2
        return np.array([f1, np.clip((u[1] + H[0, 1] * f1) / H[0, 0], -fc[1], fc[1])])

    q, v = centre.copy(), np.zeros(2)
    measured = np.round(q / count) * count
    q_prev, v_est, held = measured.copy(), np.zeros(2), np.zeros(2)
    out = []
    for k in range(int(round(seconds / period))):
        t = k * period
        q_ref = centre + np.array([-0.1 * (1 - np.cos(4 * np.pi * t)), 0.2 * (1 - np.cos(2 * np.pi * t))])
        qd_ref = np.array([-0.4 * np.pi * np.sin(4 * np.pi * t), 0.4 * np.pi * np.sin(2 * np.pi * t)])
        out.append(measured)
        v_est = alpha * v_est + beta * (measured - q_prev)
        q_prev = measured
        tau = np.clip(stiffness * (q_ref - measured) + damping * (qd_ref - v_est), -22.2, 22.2)
        code = np.clip(np.round(tau / torque_per_volt / lsb), -2048, 2047)
        command, held = held, code * lsb * torque_per_volt  # the amplifier's 1 ms delay
        for _ in range(substeps):
            qm = q + 0.5 * h * v
            vm = v + 0.5 * h * accel(q, v, command)
            vstar = v + h * accel(qm, vm, command)
            H = inertia(qm)
            f = friction(H, vstar, h)
            v_new = np.where(np.abs(f) < fc, 0.0, vstar - h * np.linalg.solve(H, f))
            q, v = q + 0.5 * h * (v + v_new), v_new
        measured = np.round(q / count) * count
    return np.array(out)


def run(args) -> dict:
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from manus.adaptive.impedance import Impedance
    from manus.plants import Manus2, Model, Simulator
    from manus.plants.closed_loop import simulate, simulate_batch
    from manus.plants.errors import ManusError
    from manus.plants.references import Complex
    from manus.runs.progress import note

    load = os.getloadavg()[0]
    if args.trials < 1 or args.seconds <= 0 or args.numpy_seconds <= 0 or args.every < 1 or args.repeats < 1:
        raise ManusError("--trials, --seconds, --numpy-seconds, --every and --repeats must be positive")
    steps = int(round(args.seconds * 1000))
    devices = len(jax.devices())
    with jax.enable_x64(not args.float32):
        plant = Simulator(Model(Manus2(), PLANT))
        reference = Complex()
        note(f"one trial of {args.seconds:g} s ...")
        single, _ = _best(lambda: simulate(plant, Impedance(), reference, args.seconds), args.repeats)
        controllers = eqx.filter_vmap(lambda k: Impedance(k, 1.0))(jnp.linspace(10.0, 60.0, args.trials))
        keys = jax.random.split(jax.random.PRNGKey(0), args.trials)

        def batch(every):
            return simulate_batch(
                plant, controllers, reference, args.seconds, keys, batched=("controller",), every=every
            )

        note(
            f"{args.trials} trials of {args.seconds:g} s on {devices} device(s), recording every {args.every} ticks ..."
        )
        light, light_cpu = _best(lambda: batch(args.every), args.repeats)
        note("... and recording every tick ...")
        full, _ = _best(lambda: batch(1), args.repeats)
        check = simulate(plant, Impedance(), reference, args.numpy_seconds).q
        dtype = str(check.dtype)

    note(f"numpy loop, {args.numpy_seconds:g} s ...")
    t0 = time.perf_counter()
    baseline = numpy_closed_loop(args.numpy_seconds)
    numpy_time = time.perf_counter() - t0
    numpy_steps = len(baseline) / numpy_time
    batch_steps = args.trials * steps / light
    return {
        "figures": {
            "single_trial_steps_per_s": steps / single,
            "batch_trial_steps_per_s": batch_steps,
            "batch_full_record_trial_steps_per_s": args.trials * steps / full,
            "numpy_steps_per_s": numpy_steps,
        },
        "speedup": batch_steps / numpy_steps,
        # on a shared machine the wall figures suffer; CPU time (all threads) much less
        "batch_cpu_ns_per_trial_step": light_cpu / (args.trials * steps) * 1e9,
        "load_average": load,
        "agreement_counts": float(np.abs(check - baseline).max() / (2 * np.pi / 131072)),
        "plant": PLANT,
        "controller": "impedance K=30 B=1 (batch: K from 10 to 60)",
        "reference": "complex",
        "trials": args.trials,
        "seconds": args.seconds,
        "numpy_seconds": args.numpy_seconds,
        "record_every": args.every,
        "substeps": plant.substeps,
        "rate_hz": plant.rate_hz,
        "dtype": dtype,
        "devices": devices,
    }


def render(r: dict) -> str:
    f = r["figures"]
    return "\n".join(
        [
            f"closed-loop simulation of the MANUS-2 arm ({r['plant']}, {r['rate_hz']:g} Hz control, "
            f"{r['substeps']} sub-steps, {r['dtype']}, {r['devices']} device(s))",
            f"  one trial ({r['seconds']:g} s):                 {f['single_trial_steps_per_s']:.3g} steps/s",
            f"  batch of {r['trials']}, record every {r['record_every']} ticks: {f['batch_trial_steps_per_s']:.3g} "
            "trial-steps/s",
            f"  batch of {r['trials']}, record every tick:     {f['batch_full_record_trial_steps_per_s']:.3g} "
            "trial-steps/s",
            f"  numpy loop ({r['numpy_seconds']:g} s, float64):     {f['numpy_steps_per_s']:.3g} steps/s",
            f"  speedup of the batch over numpy: {r['speedup']:.3g}x; numpy and JAX positions agree "
            f"within {r['agreement_counts']:.3g} encoder counts",
            f"  batch CPU time {r['batch_cpu_ns_per_trial_step']:.3g} ns per trial-step (all threads); "
            f"load average {r['load_average']:.2f} at the start",
        ]
    )
