"""`manus bench diagnose`: `diagnose` on a simulated 20 s, 2-joint, 1 kHz recording, in seconds.

The recording: the MANUS-2 arm (thesis plant `rigid,viscous,coulomb,delay` plus 39/rev cogging)
under impedance control following a multi-sine (`manus simulate`'s defaults). Timed in one run:

- `diagnose(rec, "rigid,viscous,coulomb")` with every candidate of the vocabulary (each fitted,
  its non-linear parameter searched, judged on held-out blocks; compliance from the frequency
  response), from the raw recording (the filtering and differentiation included): the first call
  (with JAX compilation of the regressor columns) and the best of `--repeats` after it;
- `manus.adaptive.fit.fit` of the nominal model alone, the same way;
- the baseline: a plain `scipy.optimize.least_squares` fit of the same model (the closed-form
  torque of the arm in numpy on the same kinematics, low-passed like the torque, on the rows `fit` uses),
  and how far its parameters are from `fit`'s.
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


def arm_torque(theta: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """τ of the absolute-angle MANUS-2 arm (thesis eqs. C.1–C.2) with viscous and Coulomb friction."""
    a1, a2, a3, b1, b2, f1, f2 = theta
    d = q[:, 1] - q[:, 0]
    c, s = np.cos(d), np.sin(d)
    t1 = a1 * qdd[:, 0] + a2 * c * qdd[:, 1] - a2 * s * qd[:, 1] ** 2 + b1 * qd[:, 0] + f1 * np.sign(qd[:, 0])
    t2 = a2 * c * qdd[:, 0] + a3 * qdd[:, 1] + a2 * s * qd[:, 0] ** 2 + b2 * qd[:, 1] + f2 * np.sign(qd[:, 1])
    return np.stack([t1, t2], 1)


def scipy_fit(data, delay: float = 0.0) -> tuple[np.ndarray, float]:
    """The baseline: non-linear least squares from a generic start; returns θ and rel_error. The
    predicted torque is low-passed like the measured one (as `fit` filters its columns), else the
    sharp sgn(q̇) is compared with a smooth torque and the fit is biased."""
    from scipy.optimize import least_squares

    from manus.estimators.offline import lowpass

    tau = data.tau(delay)

    def residual(th):
        full = arm_torque(th, data.q, data.qd, data.qdd)
        return (lowpass(full, data.dt, data.cutoff_hz)[data.rows] - tau).ravel()

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
    import jax

    from manus.adaptive.diagnose import diagnose
    from manus.adaptive.fit import fit, prepare
    from manus.plants import Manus2, Model, Simulator
    from manus.plants.closed_loop import simulate
    from manus.plants.errors import ManusError
    from manus.plants.recording import from_trajectory
    from manus.plants.references import MultiSine
    from manus.plants.simulator import workspace_centre
    from manus.adaptive.impedance import Impedance
    from manus.runs.common import note

    if args.seconds < 5 or args.repeats < 0:
        raise ManusError("--seconds must be at least 5 and --repeats not negative")
    load = os.getloadavg()[0]
    note(f"simulating {args.seconds:g} s of the arm (truth {TRUTH}) ...")
    plant = Simulator(Model(Manus2(), TRUTH))
    traj = simulate(plant, Impedance(30.0, 1.0), MultiSine(np.asarray(workspace_centre(plant.model))), args.seconds,
                    key=jax.random.PRNGKey(0))
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
    return {"figures": {"diagnose_s": d_best, "diagnose_first_call_s": d_first, "fit_s": f_best if args.repeats else f_first,
                        "fit_first_call_s": f_first, "scipy_least_squares_s": sp_best if args.repeats else sp_first},
            "diagnose_over_scipy": (d_best) / (sp_best if args.repeats else sp_first),
            "candidates": len(d.candidates), "verdict": d.verdict.spec if d.verdict else None,
            "rows": int(data.rows.size), "samples": len(rec), "cutoff_hz": data.cutoff_hz,
            "rel_error": {"fit": f.rel_error, "scipy": sp_err},
            "scipy_vs_fit_max_rel_diff": float(np.max(np.abs(theta - ref) / np.abs(ref))),
            "truth": TRUTH, "model": MODEL, "seconds": args.seconds, "repeats": args.repeats, "load_average": load,
            "cpu_count": os.cpu_count()}


def render(r: dict) -> str:
    f = r["figures"]
    return "\n".join([
        f"diagnose {r['model']} on {r['seconds']:g} s of the simulated arm (truth {r['truth']}), {r['samples']} samples "
        f"at 1 kHz -> {r['rows']} rows at a {r['cutoff_hz']:.1f} Hz cut-off, {r['cpu_count']} CPUs, load {r['load_average']:.2f}",
        f"  diagnose, {r['candidates']} candidates (verdict {r['verdict']}): {f['diagnose_s']:.2f} s "
        f"(first call, with compilation: {f['diagnose_first_call_s']:.2f} s)",
        f"  fit of the nominal model alone:          {f['fit_s']:.3f} s (first call {f['fit_first_call_s']:.2f} s)",
        f"  scipy.optimize.least_squares, same model: {f['scipy_least_squares_s']:.3f} s; its parameters within "
        f"{100 * r['scipy_vs_fit_max_rel_diff']:.2g} % of fit's (rel_error {100 * r['rel_error']['scipy']:.2f} % "
        f"against fit's {100 * r['rel_error']['fit']:.2f} %)",
        f"  diagnose costs {r['diagnose_over_scipy']:.3g} plain scipy fits",
    ])
