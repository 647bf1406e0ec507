"""`manus bench estimators`: what each velocity estimator costs.

- **per step**, as a 1 kHz loop runs it: the estimator's step compiled once
  (`manus.estimators.compiled_step`) and called from Python with a numpy measurement, the estimate
  read back to numpy; p50 and p99 of the wall time per call [µs] over `--calls` ticks (garbage
  collector off, as in a real-time loop). Beside it, in the same run: the same step under
  `eqx.filter_jit` (kalman_ca), filterpy's `KalmanFilter.predict/update` (the constant-
  acceleration filter, one per joint, the textbook numpy implementation) and a `jax.jit` of
  `x + 1`: the floor that JAX's dispatch and read-back alone cost.
- **per recording**: estimates per second over a recorded array with `lax.scan` (`manus.estimators.run`,
  jitted), best of three.
"""

from __future__ import annotations

import gc
import time

import numpy as np

HELP = "per-step latency (p50/p99) of each velocity estimator beside filterpy's Kalman filter, and scan throughput"
TARGET_P99_US = 150.0


def add_arguments(p) -> None:
    p.add_argument("--calls", type=int, default=5000, help="timed calls per estimator (default 5000)")
    p.add_argument("--samples", type=int, default=100_000, help="samples of the scanned recording (default 100000)")
    p.add_argument("--joints", type=int, default=2, help="joints (default 2, the arm)")


def _motion(samples: int, joints: int):
    from manus.estimators.linear import THESIS_STEP

    t = np.arange(samples) * 1e-3
    q = 0.1 * np.sin(2 * np.pi * np.outer(t, 0.7 + 0.9 * np.arange(joints)))
    return np.round(q / THESIS_STEP) * THESIS_STEP, 0.3 * np.cos(2 * np.pi * 1.3 * t)[:, None] * np.ones(joints)


def _percentiles(call, inputs) -> dict:
    for x in inputs[:200]:  # warm up (compilation, caches)
        call(*x)
    times = np.empty(len(inputs))
    gc.disable()
    try:
        for i, x in enumerate(inputs):
            t0 = time.perf_counter()
            call(*x)
            times[i] = time.perf_counter() - t0
    finally:
        gc.enable()
    return {"p50_us": float(np.percentile(times, 50) * 1e6), "p99_us": float(np.percentile(times, 99) * 1e6)}


def _jax_step(estimator, q0, filter_jit: bool = False):
    import equinox as eqx

    from manus.estimators import compiled_step

    step = eqx.filter_jit(estimator.step) if filter_jit else compiled_step(estimator)
    state = [estimator.init(q0)]

    def call(q, tau):
        state[0], out = step(state[0], q, tau)
        return np.asarray(out.qd)  # the loop needs the number on the host

    return call


def _filterpy_ca(q0, r):
    from manus.estimators.kalman import KinematicKalman, transition
    from manus.plants.errors import require

    Q_continuous_white_noise = require("filterpy.common", "filterpy").Q_continuous_white_noise
    KalmanFilter = require("filterpy.kalman", "filterpy").KalmanFilter

    ref = KinematicKalman(1e-3, 3, r=r)
    filters = []
    for x0 in q0:
        kf = KalmanFilter(dim_x=3, dim_z=1)
        kf.F, kf.H, kf.R = transition(3, 1e-3), np.eye(1, 3), np.array([[r]])
        kf.Q, kf.P = Q_continuous_white_noise(3, 1e-3, float(ref.q)), np.array(ref.P0)
        kf.x = np.array([[x0], [0.0], [0.0]])
        filters.append(kf)

    def call(q, tau):
        for kf, y in zip(filters, q, strict=True):
            kf.predict()
            kf.update(y)
        return np.array([kf.x[1, 0] for kf in filters])

    return call


def run(args) -> dict:
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from manus.estimators import NAMES, make
    from manus.estimators import run as scan_run
    from manus.estimators.linear import quantization_variance
    from manus.plants.errors import ManusError
    from manus.runs.progress import note

    if args.calls < 300 or args.samples < 1000 or args.joints < 1:
        raise ManusError("--calls must be at least 300, --samples at least 1000, --joints at least 1")
    q, tau = _motion(max(args.calls + 200, args.samples), args.joints)
    inputs = list(zip(q[: args.calls + 200], tau[: args.calls + 200], strict=True))
    figures, table = {}, {}

    floor = jax.jit(lambda x: x + 1)
    f = _percentiles(lambda x, _: np.asarray(floor(x)), inputs)
    figures.update({"jax_dispatch_p50_us": f["p50_us"], "jax_dispatch_p99_us": f["p99_us"]})
    f = _percentiles(_jax_step(make("kalman_ca"), jnp.asarray(q[0]), filter_jit=True), inputs)
    figures.update({"kalman_ca_filter_jit_p50_us": f["p50_us"], "kalman_ca_filter_jit_p99_us": f["p99_us"]})
    note("filterpy KalmanFilter (constant acceleration, one per joint) ...")
    f = _percentiles(_filterpy_ca(q[0], quantization_variance()), inputs)
    figures.update(
        {
            "filterpy_kalman_ca_p50_us": f["p50_us"],
            "filterpy_kalman_ca_p99_us": f["p99_us"],
            "filterpy_kalman_ca_per_s": 1e6 / f["p50_us"],
        }
    )

    scan = eqx.filter_jit(scan_run)
    qs, taus = jnp.asarray(q[: args.samples]), jnp.asarray(tau[: args.samples])
    for name in NAMES:
        note(f"{name} ...")
        est = make(name, n_joints=args.joints)
        row = _percentiles(_jax_step(est, jnp.asarray(q[0])), inputs)
        scan(est, qs, taus).qd.block_until_ready()  # compile
        best = np.inf
        for _ in range(3):
            t0 = time.perf_counter()
            scan(est, qs, taus).qd.block_until_ready()
            best = min(best, time.perf_counter() - t0)
        row["scan_per_s"] = args.samples / best
        table[name] = row
        figures.update({f"{name}_{k}": v for k, v in row.items()})
    return {
        "figures": figures,
        "estimators": table,
        "calls": args.calls,
        "samples": args.samples,
        "joints": args.joints,
        "target_p99_us": TARGET_P99_US,
        "within_target": [n for n, r in table.items() if r["p99_us"] < TARGET_P99_US],
        "speedup": table["kalman_ca"]["scan_per_s"] / figures["filterpy_kalman_ca_per_s"],
        "step_vs_filterpy": figures["filterpy_kalman_ca_p50_us"] / table["kalman_ca"]["p50_us"],
        "limit": (
            f"a jax.jit of x + 1 alone costs {figures['jax_dispatch_p50_us']:.0f} µs p50 / "
            f"{figures['jax_dispatch_p99_us']:.0f} µs p99 (dispatch, read-back, and the scheduling of a "
            f"shared CPU in the p99); the same kalman_ca step under eqx.filter_jit costs "
            f"{figures['kalman_ca_filter_jit_p50_us']:.0f} µs p50 (the module flattened and hashed per call); "
            f"in a scan the slowest estimator needs {1e6 / min(r['scan_per_s'] for r in table.values()):.1f} µs "
            f"a sample, so a single call's cost beyond the floor is XLA executing the step's operations one "
            f"by one"
        ),
    }


def render(r: dict) -> str:
    from manus.runs.text import table

    rows = [
        [
            n,
            f"{v['p50_us']:.0f}",
            f"{v['p99_us']:.0f}",
            f"{v['scan_per_s']:.3g}",
            "yes" if n in r["within_target"] else "NO",
        ]
        for n, v in r["estimators"].items()
    ]
    f = r["figures"]
    rows.append(
        [
            "filterpy KalmanFilter (CA)",
            f"{f['filterpy_kalman_ca_p50_us']:.0f}",
            f"{f['filterpy_kalman_ca_p99_us']:.0f}",
            f"{f['filterpy_kalman_ca_per_s']:.3g}",
            "",
        ]
    )
    rows.append(
        [
            "kalman_ca under eqx.filter_jit",
            f"{f['kalman_ca_filter_jit_p50_us']:.0f}",
            f"{f['kalman_ca_filter_jit_p99_us']:.0f}",
            "",
            "",
        ]
    )
    rows.append(
        ["jax.jit(x + 1): dispatch floor", f"{f['jax_dispatch_p50_us']:.0f}", f"{f['jax_dispatch_p99_us']:.0f}", "", ""]
    )
    return "\n".join(
        [
            f"per-step latency over {r['calls']} calls ({r['joints']} joints) and lax.scan over {r['samples']} samples",
            table(
                rows,
                [
                    "estimator",
                    "step p50 [µs]",
                    "step p99 [µs]",
                    "scan [samples/s]",
                    f"p99 < {r['target_p99_us']:.0f} µs",
                ],
            ),
            f"kalman_ca: a scan is {r['speedup']:.0f}x filterpy's throughput; one jitted step from Python takes "
            f"{1 / r['step_vs_filterpy']:.2f}x the time of filterpy's predict/update",
            f"limit: {r['limit']}",
        ]
    )
