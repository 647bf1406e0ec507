"""`manus bench robot`: the Panda's regressor (`manus.plants.serial.Serial`) in regressor rows per
second, beside pinocchio's `computeJointTorqueRegressor` in a Python loop, in one run.

A row is one joint's torque equation at one state (q, q̇, q̈): a state gives 7 rows (77 columns:
the ten standard parameters of each link and the armatures). JAX: the regressor `vmap`ped over an
array of random states and jitted (best of `--repeats`, compile excluded, float64). Pinocchio: one
call per state from Python, over the first `--pinocchio-states` of the same states, whose
regressors are compared with JAX's (`agreement`, the largest difference). Needs `pin` and
`example-robot-data` (the test extra: `pip install -e ".[test]"`).
"""

from __future__ import annotations

import importlib.metadata
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


def run(args) -> dict:
    import jax

    from manus.plants.errors import ManusError
    from manus.plants.serial import Serial
    from manus.runs.common import note

    if args.states < 1 or args.pinocchio_states < 1 or args.repeats < 1:
        raise ManusError("--states, --pinocchio-states and --repeats must be positive")
    try:
        import pinocchio as pin

        path = str(importlib.metadata.distribution("example-robot-data").locate_file(f"cmeel.prefix/share/{PANDA}"))
    except (ImportError, importlib.metadata.PackageNotFoundError) as e:
        raise ManusError(f"bench robot needs pinocchio and example-robot-data (pip install -e \".[test]\"): {e}") from e
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

    model = pin.buildModelFromUrdf(path)
    model = pin.buildReducedModel(model, [model.getJointId(k) for k in model.names[1:] if k not in serial.joint_names],
                                  np.zeros(model.nq))
    data = model.createData()
    m = min(args.pinocchio_states, args.states)

    def loop():
        return [pin.computeJointTorqueRegressor(model, data, q[k], qd[k], qdd[k]).copy() for k in range(m)]

    note(f"pinocchio: {m} states in a Python loop, best of {args.repeats} ...")
    pin_s = best_time(loop, args.repeats)
    order = np.concatenate([10 * j + np.array([0, 1, 2, 3, 4, 5, 7, 6, 8, 9]) for j in range(n)])
    agreement = float(np.abs(np.stack(loop())[:, :, order] - Y[:m, :, : 10 * n]).max())

    jax_rows, pin_rows = args.states * n / jax_s, m * n / pin_s
    return {"figures": {"jax_rows_per_s": jax_rows, "pinocchio_rows_per_s": pin_rows, "jax_compile_s": compile_s},
            "speedup": jax_rows / pin_rows, "agreement": agreement, "robot": "panda", "joints": n,
            "columns": Y.shape[-1], "states": args.states, "pinocchio_states": m,
            "devices": len(jax.devices()), "load_average": load}


def render(r: dict) -> str:
    f = r["figures"]
    return "\n".join([
        f"regressor of the {r['robot']} ({r['joints']} joints, {r['columns']} standard parameters), float64",
        f"  JAX, vmapped over {r['states']} states:    {f['jax_rows_per_s']:.3g} rows/s "
        f"(compile {f['jax_compile_s']:.2g} s, {r['devices']} device(s))",
        f"  pinocchio, Python loop, {r['pinocchio_states']} states: {f['pinocchio_rows_per_s']:.3g} rows/s",
        f"  speedup: {r['speedup']:.3g}x; the two agree within {r['agreement']:.2g}; "
        f"load average {r['load_average']:.2f} at the start",
    ])
