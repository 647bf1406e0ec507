"""`manus bench diagnose`: `diagnose` on a simulated 20 s, 2-joint, 1 kHz recording, in seconds.

The recording: the MANUS-2 arm (thesis plant `rigid,viscous,coulomb,delay` plus 39/rev cogging)
under impedance control following a multi-sine (`manus simulate`'s defaults). Timed in one run:

- `diagnose(rec, "rigid,viscous,coulomb")` with every candidate of the vocabulary (each fitted,
  its non-linear parameter searched, judged on held-out blocks; compliance from the frequency
  response), from the raw recording (the filtering and differentiation included): the first call
  (with JAX compilation of the regressor columns) and the best of `--repeats` after it;
- `manus.adaptive.fit` of the nominal model alone, the same way;
- the baseline: a plain `scipy.optimize.least_squares` fit of the same model (the closed-form
  torque of the arm in numpy on the same kinematics, low-passed like the torque, on the rows `fit` uses),
  and how far its parameters are from `fit`'s.

`--calibrate` instead runs the calibration set (`manus.experiments.calibration`, judged by
`manus.experiments.judging`): `--recordings` N recordings with nothing missing and N per hidden
effect of the vocabulary, each under a condition drawn from its seed, and reports the
false-alarm rate (a verdict on a recording with nothing missing), the detection rate (the
verdict names the hidden effect; and with the right joint) per effect and per condition value,
each with its Wilson 95 % interval, and the time per recording. Detection is also given over the
recordings whose hidden effect is *distinct*: at least `judging.DISTINCT` (2.5 %) of the torque
is its own, unexplained by the start model plus any one other effect
(`manus.experiments.sizing.distinct`; a delay: what it changes in the torque). Below that no
procedure can name it (a tilted plane on a small swing is an offset and a spring), so the two
rates separate what the data cannot tell from what diagnose misses. `--jobs` spreads the
recordings over worker processes (one per core by default); `--alpha` and `--blocks` run
diagnose at another family-wise level or number of held-out blocks, to see what they would trade.
"""

from __future__ import annotations

import math
import os
import time

import numpy as np

HELP = "diagnose (all candidates) on a 20 s 2-joint 1 kHz recording, beside a plain scipy least-squares fit"
TRUTH = "rigid,viscous,coulomb,delay,cogging:39"
MODEL = "rigid,viscous,coulomb"
NAMES = ("a1", "a2", "a3", "b1", "b2", "Fc1", "Fc2")


def add_arguments(p) -> None:
    p.add_argument("--seconds", type=float, default=20.0, help="length of the simulated recording [s]")
    p.add_argument("--repeats", type=int, default=2, help="best of this many timed runs after the first")
    p.add_argument(
        "--calibrate",
        action="store_true",
        help="false-alarm and detection rates over the calibration set (manus.experiments.calibration)",
    )
    p.add_argument(
        "--recordings",
        type=int,
        default=100,
        help="with --calibrate: recordings with nothing missing, and this many per hidden effect",
    )
    p.add_argument("--seed", type=int, default=0, help="with --calibrate: the first seed of the set")
    p.add_argument(
        "--effects",
        default="",
        help="with --calibrate: a comma-separated subset of the hidden effects (default: every effect; "
        "'none': the recordings with nothing missing only)",
    )
    p.add_argument(
        "--alpha",
        type=float,
        default=None,
        help="with --calibrate: the family-wise significance level diagnose uses (default: its own, "
        "manus.adaptive.ALPHA), to see what another level would give",
    )
    p.add_argument(
        "--blocks",
        type=int,
        default=None,
        help="with --calibrate: held-out blocks per recording (default: diagnose's own, manus.adaptive.BLOCKS)",
    )
    p.add_argument("--jobs", type=int, default=0, help="with --calibrate: worker processes (default: one per core)")
    p.add_argument(
        "--amplitude",
        type=float,
        default=None,
        help="with --calibrate: a hidden effect's torque RMS as a fraction of the recorded torque's "
        "(default: the set's own, 0.05); a detection curve is one run per amplitude",
    )
    p.add_argument(
        "--lost",
        type=float,
        default=0.0,
        help="with --calibrate: lose this fraction of each recording's samples at random, as a real-time "
        "loop that misses packets does (a step of 2T in t; default 0)",
    )
    p.add_argument(
        "--simulator",
        choices=("manus", "independent", "chain"),
        default="manus",
        help="with --calibrate: the recordings' simulator: manus's own, or the one written independently "
        "from the equations (regularized friction, RK4, a PD loop, read back from CSV files; "
        "manus.experiments.independent), or 6-7-joint chains (the Panda and the UR5, Coulomb or smooth "
        "friction, the UR5's wrist plain or differential, clean logs or a PC's with repeated rows and jittered "
        "stamps, each written and read back; an effect hidden on one joint, a coupling of two, or smooth "
        "friction; each recording also judged with relevance over all the torque only: manus.experiments.chains)",
    )
    p.add_argument(
        "--rates",
        default="",
        help="with --calibrate: comma-separated sample rates [Hz] the recordings are drawn at (default: "
        "the set's own, 1000,200), e.g. your rig's",
    )
    p.add_argument(
        "--robots",
        default="",
        help="with --simulator chain: comma-separated robots the recordings are drawn from (default: "
        "panda,ur5); xarm7 is the xArm7, whose URDF states a 100:1 gear on every joint, so its friction "
        "acts on the motors",
    )
    p.add_argument(
        "--no-pooled",
        dest="pooled",
        action="store_false",
        help="with --simulator chain: judge each recording with relevance per joint only, not a second time "
        "with relevance over all the torque (half the time)",
    )


def mean_sign(v: np.ndarray, a: np.ndarray, dt: float) -> np.ndarray:
    """sgn(q̇) averaged over the sample period along q̇ + q̈ s, s in [−T/2, T/2] (as `fit` averages
    its friction columns), in closed form: (|v₊| − |v₋|)/(v₊ − v₋), v± = v ± a T/2."""
    hi, lo = v + a * dt / 2, v - a * dt / 2
    crossing = (hi > 0) != (lo > 0)
    return np.where(crossing, (np.abs(hi) - np.abs(lo)) / np.where(crossing, hi - lo, 1.0), np.sign(v))


def arm_torque(theta: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, dt: float = 0.0) -> np.ndarray:
    """τ of the absolute-angle MANUS-2 arm (thesis eqs. C.1–C.2) with viscous and Coulomb friction
    (sgn averaged over the sample period `dt`)."""
    a1, a2, a3, b1, b2, f1, f2 = theta
    d = q[:, 1] - q[:, 0]
    c, s = np.cos(d), np.sin(d)
    sg = mean_sign(qd, qdd, dt)
    t1 = a1 * qdd[:, 0] + a2 * c * qdd[:, 1] - a2 * s * qd[:, 1] ** 2 + b1 * qd[:, 0] + f1 * sg[:, 0]
    t2 = a2 * c * qdd[:, 0] + a3 * qdd[:, 1] + a2 * s * qd[:, 0] ** 2 + b2 * qd[:, 1] + f2 * sg[:, 1]
    return np.stack([t1, t2], 1)


def scipy_fit(data, delay: float | np.ndarray = 0.0) -> tuple[np.ndarray, float]:
    """The baseline: non-linear least squares from a generic start; returns θ and rel_error. The
    predicted torque is low-passed like the measured one (`Data.smoothed`, as `fit` filters its
    columns: the rests left out), else the sharp sgn(q̇) is compared with a smooth torque and the
    fit is biased."""
    from scipy.optimize import least_squares

    tau = data.tau(delay)

    def residual(th):
        full = arm_torque(th, data.q, data.qd, data.qdd, data.dt)
        return (data.smoothed(data.work(full), data.rows) - tau).ravel()

    res = least_squares(residual, np.full(7, 0.1))
    return res.x, float(np.linalg.norm(res.fun) / np.linalg.norm(tau))


def _timed(fn, repeats: int):
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return out, first, best


def run(args) -> dict:
    if args.calibrate:
        return calibrate(args)
    import jax

    from manus.adaptive import diagnose, fit, prepare
    from manus.adaptive.impedance import Impedance
    from manus.plants import Manus2, Model, Simulator
    from manus.plants.closed_loop import simulate
    from manus.plants.errors import ManusError
    from manus.plants.recording import from_trajectory
    from manus.plants.references import MultiSine
    from manus.plants.simulator import workspace_centre
    from manus.runs.progress import note

    if args.seconds < 5 or args.repeats < 0:
        raise ManusError("--seconds must be at least 5 and --repeats not negative")
    load = os.getloadavg()[0]
    note(f"simulating {args.seconds:g} s of the arm (truth {TRUTH}) ...")
    plant = Simulator(Model(Manus2(), TRUTH))
    traj = simulate(
        plant,
        Impedance(30.0, 1.0),
        MultiSine(np.asarray(workspace_centre(plant.model))),
        args.seconds,
        key=jax.random.PRNGKey(0),
    )
    rec = from_trajectory(traj, plant.rate_hz, "manus2", 131072, {"truth": TRUTH})
    rec.path = "<bench: simulated arm>"
    note(f"diagnose {MODEL} (all candidates), first call then best of {args.repeats} ...")
    d, d_first, d_best = _timed(lambda: diagnose(rec, MODEL), args.repeats)
    note("fit of the nominal model alone ...")
    f, f_first, f_best = _timed(lambda: fit(rec, MODEL), args.repeats)
    note("scipy.optimize.least_squares of the same model ...")
    data = prepare(rec)
    (theta, sp_err), sp_first, sp_best = _timed(lambda: scipy_fit(data, f.delay), args.repeats)
    ref = np.array([f.params[k] for k in NAMES])
    d_best = d_first if not args.repeats else d_best
    return {
        "figures": {
            "diagnose_s": d_best,
            "diagnose_first_call_s": d_first,
            "fit_s": f_best if args.repeats else f_first,
            "fit_first_call_s": f_first,
            "scipy_least_squares_s": sp_best if args.repeats else sp_first,
        },
        "diagnose_over_scipy": (d_best) / (sp_best if args.repeats else sp_first),
        "candidates": len(d.candidates),
        "verdict": d.verdict.spec if d.verdict else None,
        "rows": int(data.rows.size),
        "samples": len(rec),
        "cutoff_hz": data.cutoff_hz,
        "rel_error": {"fit": f.rel_error, "scipy": sp_err},
        "scipy_vs_fit_max_rel_diff": float(np.max(np.abs(theta - ref) / np.abs(ref))),
        "truth": TRUTH,
        "model": MODEL,
        "seconds": args.seconds,
        "repeats": args.repeats,
        "load_average": load,
        "cpu_count": os.cpu_count(),
    }


def render(r: dict) -> str:
    if "calibration" in r:
        return render_calibration(r)
    f = r["figures"]
    return "\n".join(
        [
            f"diagnose {r['model']} on {r['seconds']:g} s of the simulated arm (truth {r['truth']}), {r['samples']} "
            "samples "
            f"at 1 kHz -> {r['rows']} rows at a {r['cutoff_hz']:.1f} Hz cut-off, {r['cpu_count']} CPUs, load "
            f"{r['load_average']:.2f}",
            f"  diagnose, {r['candidates']} candidates (verdict {r['verdict']}): {f['diagnose_s']:.2f} s "
            f"(first call, with compilation: {f['diagnose_first_call_s']:.2f} s)",
            f"  fit of the nominal model alone:          {f['fit_s']:.3f} s (first call {f['fit_first_call_s']:.2f} s)",
            f"  scipy.optimize.least_squares, same model: {f['scipy_least_squares_s']:.3f} s; its parameters within "
            f"{100 * r['scipy_vs_fit_max_rel_diff']:.2g} % of fit's (rel_error {100 * r['rel_error']['scipy']:.2f} % "
            f"against fit's {100 * r['rel_error']['fit']:.2f} %)",
            f"  diagnose costs {r['diagnose_over_scipy']:.3g} plain scipy fits",
        ]
    )


# -- the calibration set -------------------------------------------------------------------------
def run_one(
    seed: int,
    hidden: str | None,
    alpha: float | None = None,
    blocks: int | None = None,
    rates: tuple | None = None,
    amplitude: float | None = None,
    lost: float = 0.0,
    simulator: str = "manus",
    pooled: bool = True,
    robots: tuple | None = None,
) -> dict:
    """`manus.experiments.judging.judge` in a worker (float64 and the environment as everywhere:
    importing manus sets them, `manus.config`). A chain recording is judged a second time
    with relevance over all the torque only where `pooled`. JAX's compiled programs are let go
    after each recording: each recording compiles its own (its length, rate and structure), and
    their code stays mapped until then (a chain recording adds about 1800 maps; the kernel's limit
    of 65530 stopped a calibration in one process after 75 of them, with "LLVM compilation error:
    Cannot allocate memory")."""
    import jax

    from manus.experiments.judging import judge

    baseline = pooled and simulator == "chain"
    try:
        return judge(seed, hidden, alpha, blocks, rates, amplitude, lost, simulator, baseline=baseline, robots=robots)
    finally:
        jax.clear_caches()


def _robots(args, simulator: str) -> tuple | None:
    """`--robots` as a tuple (None: the set's own), checked against the chains there are."""
    given = [r.strip() for r in args.robots.split(",") if r.strip()]
    if not given:
        return None
    from manus.experiments import chains
    from manus.plants.errors import ManusError

    if simulator != "chain":
        raise ManusError("--robots: only with --simulator chain (the other sets are the thesis's arm and axis)")
    bad = [r for r in given if r not in chains.ROBOTS]
    if bad:
        raise ManusError(f"--robots: unknown robot(s) {', '.join(bad)}: the chain set has {', '.join(chains.ROBOTS)}")
    return tuple(dict.fromkeys(given))


def calibrate(args) -> dict:
    from manus.adaptive import ALPHA, BLOCKS
    from manus.experiments import calibration
    from manus.experiments.judging import case_seed, summarize
    from manus.plants.errors import ManusError
    from manus.runs.progress import note

    n = args.recordings
    if n < 1:
        raise ManusError("--recordings must be at least 1")
    simulator = args.simulator
    robots = _robots(args, simulator)
    if simulator == "independent":
        from manus.experiments import independent
    from manus.experiments import chains

    vocabulary = {"independent": lambda: independent.EFFECTS, "chain": lambda: chains.HIDDEN}.get(
        simulator, calibration.hidden_effects
    )()
    effects = vocabulary
    if args.effects.strip().lower() == "none":  # the null recordings only: the false-alarm rate
        effects = ()
    elif args.effects:
        chosen = [e.strip() for e in args.effects.split(",") if e.strip()]
        bad = [e for e in chosen if e not in effects]
        if bad:
            raise ManusError(
                f"--effects: unknown effect(s) {', '.join(bad)}: the {simulator} simulator hides {', '.join(effects)}"
            )
        effects = tuple(chosen)
    rates = {"independent": lambda: independent.RATES, "chain": lambda: chains.RATES}.get(
        simulator, lambda: calibration.RATES
    )()
    if args.rates:
        try:
            rates = calibration.check_rates([float(r) for r in args.rates.split(",") if r.strip()])
        except ValueError:
            raise ManusError(
                f"--rates {args.rates!r}: comma-separated sample rates, whole numbers of Hz from 100 "
                "to 20000 (e.g. 500,2000)"
            ) from None
    amplitude = args.amplitude
    try:
        amplitude = calibration.check_amplitude(calibration.AMPLITUDE if amplitude is None else amplitude)
    except ValueError as e:
        raise ManusError(f"--amplitude: {e}") from None
    plan = [(case_seed(args.seed, 0, i), None) for i in range(n)]
    plan += [(case_seed(args.seed, 1 + vocabulary.index(e), i), e) for e in effects for i in range(n)]
    note(
        f"calibration: {n} recordings with nothing missing and {n} per hidden effect ({', '.join(effects)}): "
        f"{len(plan)} in all"
    )
    if args.alpha is not None and not 0 < args.alpha < 1:
        raise ManusError(f"--alpha must lie between 0 and 1 (got {args.alpha})")
    jobs = args.jobs or os.cpu_count() or 1
    if jobs < 1:
        raise ManusError(f"--jobs must be at least 1 (got {jobs})")
    t0 = time.perf_counter()
    results = []
    blocks = args.blocks
    if blocks is not None and blocks < 3:
        raise ManusError(f"--blocks must be at least 3 (got {blocks})")
    lost = args.lost
    if not 0 <= lost < 0.5:
        raise ManusError(f"--lost must lie in [0, 0.5) (got {lost})")
    pooled = getattr(args, "pooled", True)
    for k, r in enumerate(_each(plan, args.alpha, blocks, jobs, rates, amplitude, lost, simulator, pooled, robots), 1):
        seed, hidden = r["seed"], r["hidden"]
        results.append(r)
        if r["outcome"] in ("crash", "error", "false alarm", "missed", "wrong", "reading"):
            c = r.get("condition", {})
            note(
                f"  [{k}/{len(plan)}] hidden {hidden or 'nothing'} (seed {seed}, {c.get('structure')} "
                f"{c.get('rate')} Hz "
                f"{c.get('excitation')} {c.get('torque')} hold {c.get('hold')}"
                + "".join(f" {k} {c[k]}" for k in ("friction", "transmission", "log", "engine") if k in c)
                + (f" {c['hidden_spec']}" if "hidden_spec" in c else "")
                + f"): {r['outcome']}"
                + (f" {r.get('verdict_spec')}" if r.get("verdict_spec") else "")
                + (f" (reads as {' or '.join(r['verdict_reads_as'])})" if r.get("verdict_reads_as") else "")
                + (f": {r['error']}" if "error" in r else "")
            )
        elif k % 5 == 0 or k == len(plan):
            spent = time.perf_counter() - t0
            note(f"  [{k}/{len(plan)}] {spent:.0f} s, about {spent / k * (len(plan) - k):.0f} s left")
    summary = summarize(results)
    wall = time.perf_counter() - t0
    crashes = {}
    for r in results:
        if r["outcome"] == "crash":
            crashes.setdefault(
                r["error"].splitlines()[0][:200],
                {"count": 0, "seed": r["seed"], "hidden": r["hidden"], "trace": r.get("trace", "")},
            )["count"] += 1
    return {
        "figures": {
            "false_alarm_rate": summary["false_alarm"]["rate"],
            "detection_rate": summary["detection"]["named"]["rate"],
            "detection_rate_with_readings": summary["detection"]["named_or_reading"]["rate"],
            "diagnose_s_per_recording": summary["diagnose_s_per_recording"]["mean"],
            "wall_s": wall,
        },
        "calibration": summary,
        "crashes": crashes,
        "recordings": n,
        "seed": args.seed,
        "effects": list(effects),
        "amplitude": amplitude,
        "alpha": args.alpha if args.alpha is not None else ALPHA,
        "jobs": jobs,
        "blocks": blocks if blocks is not None else BLOCKS,
        "rates": list(rates),
        "lost": lost,
        "simulator": simulator,
        "pooled": pooled and simulator == "chain",
        "robots": list(robots) if robots else None,
        "results": [{k: v for k, v in r.items() if k != "trace"} for r in results],
        "load_average": os.getloadavg()[0],
        "cpu_count": os.cpu_count(),
    }


def _each(
    plan: list,
    alpha: float | None,
    blocks: int | None,
    jobs: int,
    rates: tuple | None = None,
    amplitude: float | None = None,
    lost: float = 0.0,
    simulator: str = "manus",
    pooled: bool = True,
    robots: tuple | None = None,
):
    """`run_one` over the plan, in order: in this process (one job) or in `jobs` fresh worker
    processes (spawned, not forked: JAX is not fork-safe), each compiling its own simulations."""
    if jobs == 1 or len(plan) < 2:
        for seed, hidden in plan:
            yield run_one(seed, hidden, alpha, blocks, rates, amplitude, lost, simulator, pooled, robots)
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(min(jobs, len(plan)), mp_context=multiprocessing.get_context("spawn")) as pool:
        yield from pool.map(
            run_one,
            *zip(*plan, strict=True),
            [alpha] * len(plan),
            [blocks] * len(plan),
            [rates] * len(plan),
            [amplitude] * len(plan),
            [lost] * len(plan),
            [simulator] * len(plan),
            [pooled] * len(plan),
            [robots] * len(plan),
        )


def _pct(r: dict) -> str:
    if not r["n"]:
        return "-"
    return f"{100 * r['rate']:5.1f} % [{100 * r['lo']:.0f}, {100 * r['hi']:.0f}] ({r['k']}/{r['n']})"


def render_calibration(r: dict) -> str:
    s = r["calibration"]
    at = (
        f", at {'/'.join(str(x) for x in r['rates'])} Hz" if r.get("rates") and tuple(r["rates"]) != (1000, 200) else ""
    )
    by = {
        "independent": " (the independent simulator: manus.experiments.independent)",
        "chain": " (6-7-joint chains: manus.experiments.chains)",
    }.get(r.get("simulator", ""), "")
    lines = [
        f"calibration{by}: {r['recordings']} recordings per row, seed {r['seed']}{at}, hidden at "
        f"{100 * r['amplitude']:g} % of the torque RMS"
        + (f", {100 * r['lost']:g} % of the samples lost at random" if r.get("lost") else "")
        + f", alpha {r.get('alpha', '-')}, {r.get('blocks', '-')} held-out blocks; rates with Wilson 95 % intervals",
        f"  false alarms (verdict on nothing missing):  {_pct(s['false_alarm'])}"
        + (f"  verdicts: {s['false_alarm_verdicts']}" if s["false_alarm_verdicts"] else "")
        + (f"  (and {s['null_errors']} refused with a ManusError)" if s.get("null_errors") else ""),
        f"  detection (verdict = hidden effect):       {_pct(s['detection']['named'])}",
        f"  ... or among the verdict's readings:       {_pct(s['detection']['named_or_reading'])}  (the verdict "
        "names the hidden effect as a reading this recording cannot tell from it)",
        f"  ... of those, on the right joint:          {_pct(s['detection']['right_joint'])}",
        f"  detection where the hidden effect is distinct (>= {100 * s['detection_where_distinct']['threshold']:g} % "
        f"of the torque no other reading explains): {_pct(s['detection_where_distinct']['named'])}",
        *(
            [
                f"  where its distinct share is at or above the detection limit diagnose states for it: "
                f"{_pct(s['detection_by_limit']['at_or_above']['named'])}; below it: "
                f"{_pct(s['detection_by_limit']['below']['named'])}"
            ]
            if "detection_by_limit" in s
            else []
        ),
        *(
            [
                f"  with relevance over all the torque only (the same recordings): false alarms "
                f"{_pct(s['before']['false_alarm'])}; detection {_pct(s['before']['detection']['named'])}; "
                f"on the right joint {_pct(s['before']['detection']['right_joint'])}"
            ]
            if s.get("before")
            else []
        ),
        f"  'something left' on nothing missing:      {_pct(s['unexplained_on_null'])}",
        f"  'something left' where an effect was missed: {_pct(s['unexplained_when_missed'])}",
        "",
        f"{'hidden effect':<14}{'named':<32}{'right joint':<32}verdicts",
    ]
    lines[-1] = f"{'hidden effect':<14}{'named':<32}{'or a reading':<32}{'named where distinct':<32}verdicts"
    where = s["detection_where_distinct"]["per_effect"]
    for name, e in s["per_effect"].items():
        d = where.get(name, {}).get("named", {"n": 0})
        lines.append(f"{name:<14}{_pct(e['named']):<32}{_pct(e['named_or_reading']):<32}{_pct(d):<32}{e['verdicts']}")
    lines += ["", f"{'condition':<24}{'false alarm':<32}{'named':<32}named or a reading, on its joint"]
    for key, values in s["per_condition"].items():
        for v, x in values.items():
            lines.append(
                f"{key + '=' + v:<24}{_pct(x['false_alarm']):<32}{_pct(x['named']):<32}{_pct(x['right_joint'])}"
            )
    t = s["diagnose_s_per_recording"]
    lines += [
        "",
        f"time per recording: diagnose {t['mean']:.2f} s mean, {t['median']:.2f} s median, {t['max']:.2f} s max; "
        f"simulation {s['simulate_s_per_recording']['mean']:.2f} s mean; wall {r['figures']['wall_s']:.0f} s"
        if t["mean"] is not None
        else "time per recording: -",
        f"errors (ManusError): {s['errors']}, crashes (any other exception): {s['crashes']}",
    ]
    for msg, c in r["crashes"].items():
        lines.append(f"  crash x{c['count']} (first: seed {c['seed']}, hidden {c['hidden']}): {msg}")
    return "\n".join(lines)
