"""`manus bench robot`: the Panda's regressor (`manus.plants.serial.Serial`) in regressor rows per
second, beside pinocchio's `computeJointTorqueRegressor` in a Python loop, in one run; then the
Panda simulated (1 kHz, 2 sub-steps, viscous and Coulomb friction per joint and an offset on joint
4, tracking a Fourier excitation under a feed-forward controller: the acceptance test's set-up)
for `--fit-seconds` as one trial, `manus fit` of `rigid,viscous,coulomb,offset` on that recording
(first call and best of `--repeats`), and a vmapped batch of `--trials` trials of
`--batch-seconds` (trial-steps per second beside the single trial's steps per second). Then, on
the Panda simulated `--arm-seconds` at 1 kHz and the UR5 `--ur5-seconds` at 5 kHz (viscous and
Coulomb friction per joint, an offset on one joint), each of `manus fit`, `diagnose` and
`discover` (`--commands`) run as a user runs it, in a new process (compilation included, JAX's
persistent cache as the user's environment has it), beside the textbook baseline run in this
process: pinocchio's `computeJointTorqueRegressor` at every sample with viscous, Coulomb and
offset columns, solved by `numpy.linalg.lstsq`.

A row is one joint's torque equation at one state (q, q̇, q̈): a state gives 7 rows (77 columns:
the ten standard parameters of each link and the armatures). JAX: the regressor `vmap`ped over an
array of random states and jitted (best of `--repeats`, compile excluded, float64). Pinocchio: one
call per state from Python, over the first `--pinocchio-states` of the same states, whose
regressors are compared with JAX's (`agreement`, the largest difference). Needs `pin` and
`example-robot-data` (the test extra: `pip install -e ".[test]"`).
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import time

import numpy as np

from manus.runs.bench import best_time

HELP = "the Panda's regressor rows per second: vmapped JAX beside pinocchio in a Python loop"
PANDA = "example-robot-data/robots/panda_description/urdf/panda.urdf"


def add_arguments(p) -> None:
    p.add_argument("--states", type=int, default=20000, help="random states in the JAX array")
    p.add_argument("--pinocchio-states", type=int, default=2000, help="states in pinocchio's Python loop")
    p.add_argument("--repeats", type=int, default=3, help="best of this many timed runs")
    p.add_argument(
        "--fit-seconds",
        type=float,
        default=60.0,
        help="length of the simulated Panda recording that manus fit is timed on [s] (0: skip)",
    )
    p.add_argument("--trials", type=int, default=8, help="trials in the simulator's vmapped batch")
    p.add_argument("--batch-seconds", type=float, default=1.0, help="length of each batched trial [s]")
    p.add_argument(
        "--arm-seconds",
        type=float,
        default=20.0,
        help="length of the simulated Panda recording (1 kHz) that the commands are timed on [s] (0: skip)",
    )
    p.add_argument(
        "--ur5-seconds",
        type=float,
        default=9.0,
        help="length of the simulated UR5 recording (5 kHz) that the commands are timed on [s] (0: skip)",
    )
    p.add_argument(
        "--commands",
        default=",".join(COMMANDS),
        help="the commands timed in new processes on each arm's recording (comma-separated)",
    )


def run(args) -> dict:
    import jax

    from manus.plants.errors import ManusError
    from manus.plants.serial import Serial
    from manus.runs.progress import note

    if args.states < 1 or args.pinocchio_states < 1 or args.repeats < 1 or args.trials < 1 or args.batch_seconds <= 0:
        raise ManusError("--states, --pinocchio-states, --repeats, --trials and --batch-seconds must be positive")
    commands = [c.strip() for c in args.commands.split(",") if c.strip()]
    unknown = sorted(set(commands) - set(COMMANDS))
    if unknown:
        raise ManusError(f"--commands: unknown {', '.join(unknown)} (expected some of {', '.join(COMMANDS)})")
    try:
        import pinocchio as pin

        path = str(importlib.metadata.distribution("example-robot-data").locate_file(f"cmeel.prefix/share/{PANDA}"))
    except (ImportError, importlib.metadata.PackageNotFoundError) as e:
        raise ManusError(f'bench robot needs pinocchio and example-robot-data (pip install -e ".[test]"): {e}') from e
    load = os.getloadavg()[0]
    serial = Serial.from_urdf(path)
    n = serial.n_joints
    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi, np.pi, (args.states, n))
    qd, qdd = rng.standard_normal((2, args.states, n))

    with jax.enable_x64(True):
        regressors = jax.jit(jax.vmap(serial.regressor))
        note(f"JAX: compiling the regressor for {args.states} states ...")
        t0 = time.perf_counter()
        Y = np.asarray(regressors(q, qd, qdd))
        compile_s = time.perf_counter() - t0
        note(f"JAX: best of {args.repeats} ...")
        jax_s = best_time(lambda: regressors(q, qd, qdd).block_until_ready(), args.repeats)

    model = pin.buildModelFromUrdf(path)  # pyright: ignore[reportAttributeAccessIssue] (pinocchio's compiled module has no stubs)
    model = pin.buildReducedModel(  # pyright: ignore[reportAttributeAccessIssue] (pinocchio's compiled module has no stubs)
        model, [model.getJointId(k) for k in model.names[1:] if k not in serial.joint_names], np.zeros(model.nq)
    )
    data = model.createData()
    m = min(args.pinocchio_states, args.states)

    def loop():
        return [
            pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k]).copy()  # pyright: ignore[reportAttributeAccessIssue] (pinocchio's compiled module has no stubs)
            for k in range(m)
        ]

    note(f"pinocchio: {m} states in a Python loop, best of {args.repeats} ...")
    pin_s = best_time(loop, args.repeats)
    order = np.concatenate([10 * j + np.array([0, 1, 2, 3, 4, 5, 7, 6, 8, 9]) for j in range(n)])
    agreement = float(np.abs(np.stack(loop())[:, :, order] - Y[:m, :, : 10 * n]).max())

    jax_rows, pin_rows = args.states * n / jax_s, m * n / pin_s
    out = {
        "figures": {"jax_rows_per_s": jax_rows, "pinocchio_rows_per_s": pin_rows, "jax_compile_s": compile_s},
        "speedup": jax_rows / pin_rows,
        "agreement": agreement,
        "robot": "panda",
        "joints": n,
        "columns": Y.shape[-1],
        "states": args.states,
        "pinocchio_states": m,
        "devices": len(jax.devices()),
        "load_average": load,
    }
    if args.fit_seconds > 0:
        out["figures"].update(_loop(path, args, note))
        out.update(fit_seconds=args.fit_seconds, trials=args.trials, batch_seconds=args.batch_seconds)
    arms = [(a, sec) for a, sec in (("panda", args.arm_seconds), ("ur5", args.ur5_seconds)) if sec > 0]
    if arms and commands:
        out["arms"] = [_arm(a, sec, commands, note) for a, sec in arms]
    return out


UR5 = "example-robot-data/robots/ur_description/urdf/ur5_robot.urdf"
COMMANDS = ("fit", "diagnose", "discover")
# the model each command starts from on an arm's recording (the truth: rigid,viscous,coulomb,offset)
COMMAND_MODEL = {"fit": "rigid,viscous,coulomb,offset", "diagnose": "rigid,viscous,coulomb", "discover": "rigid"}
FC = (0.5, 0.5, 0.4, 0.4, 0.3, 0.3, 0.2)  # Coulomb [N·m] per joint
B = (0.3, 0.3, 0.25, 0.25, 0.15, 0.15, 0.1)  # viscous [N·m·s/rad]
HIDDEN = {"off4": 0.5}  # one hidden effect on one joint of seven: a constant 0.5 N·m on joint 4
CENTRE = (0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8)
MODEL = "rigid,viscous,coulomb,offset"


def panda_case(path: str):
    """The Panda (its URDF at `path`, armatures 0.1..0.3 kg m²) with
    viscous and Coulomb friction per joint and an offset on joint 4, 1 kHz, 2 sub-steps, and the
    Fourier excitation it tracks: (serial, simulator, reference, truth)."""
    from manus.plants import Model, Simulator
    from manus.plants.serial import Serial
    from manus.plants.serial_sim import Fourier

    serial = Serial.from_urdf(path, armature=np.linspace(0.1, 0.3, 7))
    truth = {
        **{f"b{i + 1}": v for i, v in enumerate(B)},
        **{f"Fc{i + 1}": v for i, v in enumerate(FC)},
        **{f"off{i + 1}": 0.0 for i in range(7)},
        **HIDDEN,
    }
    centre = np.array(CENTRE)
    sim = Simulator(Model(serial, MODEL), truth, substeps=2, actuator=None, q0=centre)
    return serial, sim, Fourier(centre, amplitude=1.0, f0=0.2, harmonics=6, decay=1.5, seed=1), truth


def ur5_case(path: str):
    """The UR5 (its URDF at `path`, armatures 0.1..0.3 kg m²) with viscous and Coulomb friction
    per joint and an offset on joint 2, 5 kHz, 2 sub-steps, and the Fourier excitation it tracks:
    (serial, simulator, reference, truth)."""
    from manus.plants import Model, Simulator
    from manus.plants.serial import Serial
    from manus.plants.serial_sim import Fourier

    serial = Serial.from_urdf(path, armature=np.linspace(0.1, 0.3, 6))
    truth = {
        **{f"b{i + 1}": v for i, v in enumerate((2.0, 2.0, 1.5, 0.5, 0.5, 0.4))},
        **{f"Fc{i + 1}": v for i, v in enumerate((3.0, 3.0, 2.0, 0.8, 0.8, 0.6))},
        **{f"off{i + 1}": 0.0 for i in range(6)},
        "off2": 1.5,
    }
    centre = np.array((0.0, -1.2, 1.2, -1.5, -1.5, 0.0))
    sim = Simulator(Model(serial, MODEL), truth, rate_hz=5000.0, substeps=2, actuator=None, q0=centre)
    return serial, sim, Fourier(centre, amplitude=0.8, f0=0.2, harmonics=6, decay=1.5, seed=1), truth


def _arm(arm: str, seconds: float, commands: list[str], note) -> dict:
    """One arm simulated for `seconds` and written as a recording; each of `commands` run on it
    in a new process (wall time, compilation included), beside the pinocchio baseline in this one."""
    import subprocess
    import sys
    import tempfile

    import jax

    from manus.plants.errors import ManusError
    from manus.plants.recording import write
    from manus.plants.serial_sim import record

    path = _urdf(UR5 if arm == "ur5" else PANDA)
    with jax.enable_x64(True):
        serial, sim, reference, _ = (ur5_case if arm == "ur5" else panda_case)(path)
        note(f"simulating {seconds:g} s of the {arm} at {sim.rate_hz:g} Hz ...")
        rec = record(sim, reference, seconds)
    out: dict = {"robot": arm, "joints": serial.n_joints, "seconds": seconds, "rate_hz": sim.rate_hz}
    out["baseline"] = baseline(path, serial, rec)
    with tempfile.TemporaryDirectory(prefix="manus-bench-") as tmp:
        csv = str(write(rec, os.path.join(tmp, f"{arm}.csv")))
        for c in commands:
            note(f"manus {c} --model {COMMAND_MODEL[c]} on the {arm}'s recording, a new process ...")
            argv = [sys.executable, "-m", "manus.runs.cli", c, csv, "--model", COMMAND_MODEL[c], "--json"]
            t0, c0, load = time.perf_counter(), _children_cpu(), os.getloadavg()[0]
            done = subprocess.run([*argv, "--out", tmp], capture_output=True, text=True, check=False)
            wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
            if done.returncode:
                raise ManusError(f"manus {c} on the simulated {arm} failed: {done.stderr.strip()[-300:]}")
            r = json.loads(done.stdout)
            out[c] = {"s": wall, "cpu_s": cpu, "load_average": load, "rel_error": r["rel_error"]}
            out[c]["model"] = r.get("spec", r.get("model"))
            if c == "diagnose":
                out[c]["verdict"] = r.get("verdict_spec")
    return out


def _children_cpu() -> float:
    """CPU seconds (user and system) of the finished child processes so far: on a shared machine
    a command's CPU time moves far less with the other work than its wall time."""
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _urdf(relative: str) -> str:
    return str(importlib.metadata.distribution("example-robot-data").locate_file(f"cmeel.prefix/share/{relative}"))


def baseline(path: str, serial, rec) -> dict:
    """Least squares the textbook way on the recording's samples: pinocchio's
    `computeJointTorqueRegressor` at every sample (the true velocities, q̈ their central
    difference), viscous, Coulomb and offset columns per joint, `numpy.linalg.lstsq`; its wall
    time (the regressor's Python loop and the solve) and torque rel_error (unfiltered)."""
    import pinocchio as pin

    model = pin.buildModelFromUrdf(path)  # pyright: ignore[reportAttributeAccessIssue] (pinocchio's compiled module has no stubs)
    model = pin.buildReducedModel(  # pyright: ignore[reportAttributeAccessIssue] (pinocchio's compiled module has no stubs)
        model, [model.getJointId(k) for k in model.names[1:] if k not in serial.joint_names], np.zeros(model.nq)
    )
    data = model.createData()
    q, qd = rec.q, rec.qd
    qdd = np.gradient(qd, rec.dt, axis=0)
    T, n = q.shape
    t0 = time.perf_counter()
    rigid = np.stack(
        [
            pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k]).copy()  # pyright: ignore[reportAttributeAccessIssue] (pinocchio's compiled module has no stubs)
            for k in range(T)
        ]
    )  # (T, n, 10 n)
    eye = np.eye(n)
    per_joint = [qdd, qd, np.sign(qd), np.ones_like(qd)]  # armature, viscous, Coulomb, offset
    Y = np.concatenate([rigid, *(x[:, :, None] * eye for x in per_joint)], axis=2).reshape(T * n, -1)
    tau = rec.tau.reshape(-1)
    theta = np.linalg.lstsq(Y, tau, rcond=None)[0]
    wall = time.perf_counter() - t0
    return {"s": wall, "rows": T, "rel_error": float(np.linalg.norm(tau - Y @ theta) / np.linalg.norm(tau))}


def accuracy(f, truth: dict, columns=None) -> dict:
    """How well the fit `f` of the Panda case recovered `truth` (base parameters and effects by
    name): per parameter, the most of a joint's torque (RMS over its used equations) it carries
    and its relative error; the acceptance asks those carrying at least 1 % within 1 % (`worst`),
    and the others to add under 0.1 % of every joint's torque in error (`others_add`)."""
    from manus.adaptive import Columns

    data = f.data
    cols = columns or Columns(data)
    Y, tau = cols.model(f.model), data.tau(f.delay)
    used = np.maximum(data.mask.sum(0), 1) if data.mask is not None else np.full(data.n_joints, len(tau))
    rms_tau = np.sqrt((tau**2).sum(0) / used)
    rms_col = np.sqrt((Y**2).sum(0) / used[:, None])  # (n, P)
    rows = []
    for i, k in enumerate(f.names):
        share = float(np.max(abs(truth[k]) * rms_col[:, i] / rms_tau))
        err = f.params[k] - truth[k]
        rows.append(
            {
                "name": k,
                "share": share,
                "error": abs(err) / abs(truth[k]) if truth[k] else float("inf"),
                "adds": float(np.max(abs(err) * rms_col[:, i] / rms_tau)),
            }
        )
    carrying = [r for r in rows if r["share"] >= 0.01]
    others = [r for r in rows if r["share"] < 0.01]
    worst = max(carrying, key=lambda r: r["error"])
    return {
        "carrying": [r["name"] for r in carrying],
        "worst": worst["error"],
        "worst_name": worst["name"],
        "others": len(others),
        "others_add": max((r["adds"] for r in others), default=0.0),
        "rows": rows,
    }


def _loop(path: str, args, note) -> dict:
    """The Panda simulated (one trial, then a vmapped batch) and fitted: seconds and rates."""
    import jax

    from manus.adaptive import diagnose, fit
    from manus.plants.closed_loop import simulate_batch
    from manus.plants.errors import ManusError
    from manus.plants.serial_sim import Feedforward, record

    with jax.enable_x64(True):
        serial, sim, reference, truth = panda_case(path)
        note(f"simulating {args.fit_seconds:g} s of the Panda (one trial, with compilation) ...")
        t0 = time.perf_counter()
        rec = record(sim, reference, args.fit_seconds)
        sim_s = time.perf_counter() - t0
        note(f"manus fit {MODEL} on it, first call then best of {args.repeats} ...")
        t0 = time.perf_counter()
        fitted = fit(rec, MODEL)
        fit_first = time.perf_counter() - t0
        fit_s = best_time(lambda: fit(rec, MODEL), args.repeats)
        note("the acceptance on it: the base parameters against the truth, and diagnose from rigid,viscous,coulomb ...")
        base = serial.base()
        acc = accuracy(fitted, {**truth, **dict(zip(base.rigid_names, base.values(serial.defaults), strict=True))})
        t0 = time.perf_counter()
        try:
            # with the method the fit chose on this recording (diagnose's own choice would run IV's
            # simulations again for the smaller model)
            verdict = diagnose(fitted.data, "rigid,viscous,coulomb", method=fitted.method).verdict
        except ManusError as e:  # too short a recording: said, not a crash of the bench
            note(f"diagnose: {e}")
            verdict = None
        diagnose_s = time.perf_counter() - t0
        note(f"{args.trials} trials of {args.batch_seconds:g} s vmapped ...")
        keys = jax.random.split(jax.random.PRNGKey(0), args.trials)
        controller = Feedforward(serial, sim.dt)
        batch = lambda: simulate_batch(sim, controller, reference, args.batch_seconds, keys, every=10)
        batch()  # compile
        batch_s = best_time(batch, max(1, args.repeats - 1))
    steps = int(round(args.batch_seconds * sim.rate_hz))
    return {
        "simulate_one_trial_steps_per_s": len(rec) / sim_s,
        "fit_first_call_s": fit_first,
        "fit_s": fit_s,
        "fit_rel_error": fitted.rel_error,
        "batch_trial_steps_per_s": args.trials * steps / batch_s,
        "fit_method": fitted.method,
        "base_worst_error": acc["worst"],
        "base_worst_name": acc["worst_name"],
        "base_carrying": len(acc["carrying"]),
        "base_others_add": acc["others_add"],
        "diagnose_verdict": None if verdict is None else verdict.spec,
        "diagnose_joint": None if verdict is None else int(verdict.joint),
        "diagnose_s": diagnose_s,
    }


def render(r: dict) -> str:
    f = r["figures"]
    return "\n".join(
        [
            f"regressor of the {r['robot']} ({r['joints']} joints, {r['columns']} standard parameters), float64",
            f"  JAX, vmapped over {r['states']} states:    {f['jax_rows_per_s']:.3g} rows/s "
            f"(compile {f['jax_compile_s']:.2g} s, {r['devices']} device(s))",
            f"  pinocchio, Python loop, {r['pinocchio_states']} states: {f['pinocchio_rows_per_s']:.3g} rows/s",
            f"  speedup: {r['speedup']:.3g}x; the two agree within {r['agreement']:.2g}; "
            f"load average {r['load_average']:.2f} at the start",
        ]
        + (
            [
                "the Panda simulated at 1 kHz (2 sub-steps, friction per joint, coupled stick-slip), fitted by manus "
                "fit:",
                f"  one trial of {r['fit_seconds']:g} s: {f['simulate_one_trial_steps_per_s']:.3g} steps/s "
                "(compilation included)",
                f"  batch of {r['trials']} trials of {r['batch_seconds']:g} s, vmapped: "
                f"{f['batch_trial_steps_per_s']:.3g} trial-steps/s",
                f"  manus fit on the {r['fit_seconds']:g} s: {f['fit_s']:.2f} s (first call "
                f"{f['fit_first_call_s']:.2f} s), "
                f"rel_error {100 * f['fit_rel_error']:.3g} %",
                f"  the acceptance ({f['fit_method']}): the {f['base_carrying']} parameters carrying >= 1 % of a "
                "joint's torque "
                f"within {100 * f['base_worst_error']:.2g} % ({f['base_worst_name']} the worst), the others adding "
                "under "
                f"{100 * f['base_others_add']:.2g} % of a joint's torque; diagnose from rigid,viscous,coulomb: "
                f"{f['diagnose_verdict']} on joint {f['diagnose_joint']} (the hidden: offset on joint 4) in "
                f"{f['diagnose_s']:.1f} s",
            ]
            if "fit_s" in f
            else []
        )
        + [line for a in r.get("arms", []) for line in _arm_lines(a)]
    )


def _arm_lines(a: dict) -> list[str]:
    b = a["baseline"]
    lines = [
        f"the {a['robot']} ({a['joints']} joints) simulated {a['seconds']:g} s at {a['rate_hz']:g} Hz; each command "
        "in a new process (compilation included):"
    ]
    for c in COMMANDS:
        if c in a:
            x = a[c]
            extra = f", verdict {x['verdict']}" if c == "diagnose" else ""
            lines.append(
                f"  manus {c} --model {COMMAND_MODEL[c]}: {x['s']:.1f} s, {x['cpu_s']:.1f} s CPU at load "
                f"{x['load_average']:.1f} (ends at {x['model']}, rel_error "
                f"{100 * x['rel_error']:.3g} %{extra})"
            )
    lines.append(
        f"  baseline in this process, pinocchio's regressor at the {b['rows']} samples + numpy lstsq: {b['s']:.2f} s "
        f"(rel_error {100 * b['rel_error']:.3g} %)"
    )
    return lines
