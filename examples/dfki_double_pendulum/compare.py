"""The DFKI double pendulum in MANUS-2's absolute angles and in its own relative coordinates.

For each recording (the absolute-angle exports in ../shared/data/real/dfki_double_pendulum):

1. the torque error of two fits on the same samples: MANUS-2's structure (`rigid,viscous,coulomb,
   gravity`: friction on the absolute link rates) and the serial chain of `double_pendulum_a0.urdf`
   in relative coordinates (`rigid,viscous,coulomb`: gravity is in a serial chain's `rigid`, and
   the elbow's friction acts on the relative rate, where its motor puts it). Both keep every sample
   of the window, standstill included (the two structures leave out different samples at rest),
   with the same cut-off, and both errors are measured on the same torques: the absolute-angle
   ones of the export (MANUS-2's) and the motor torques (the chain's);
2. the chain's parameters as `manus fit` gives them (its defaults), beside DFKI's model_2.0.

    python examples/dfki_double_pendulum/compare.py ../shared/data/real/dfki_double_pendulum/A0_trajectory_0*.csv
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from to_relative import relative

MANUS2 = "rigid,viscous,coulomb,gravity"
CHAIN = "rigid,viscous,coulomb"
# DFKI's model_2.0 friction (NOTES.md of the data): b held at 0.001, Coulomb (as cf atan(100 q̇))
PUBLISHED_FRICTION = {"b1": 0.001, "b2": 0.001, "Fc1": 0.093, "Fc2": 0.078}
# motor torques -> the absolute angles' generalized forces (virtual work): tau1 = m1 - m2, tau2 = m2
TO_ABSOLUTE = np.array([[1.0, -1.0], [0.0, 1.0]])


def _error(residual: np.ndarray, tau: np.ndarray) -> float:
    return float(np.linalg.norm(residual) / np.linalg.norm(tau))


def compare_one(path: str | Path) -> dict:
    from manus.adaptive import fit, prepare
    from manus.plants import recording

    absolute = recording.read(path)
    chain = relative(path)
    da = prepare(absolute, None, exclude_standstill=False)
    dr = prepare(chain, da.cutoff_hz, exclude_standstill=False)
    fa, fr = fit(da, MANUS2), fit(dr, CHAIN)
    to_motor = np.linalg.inv(TO_ABSOLUTE)
    ta, tr = da.tau(fa.delay), dr.tau(fr.delay)
    same = {
        "samples": int(da.rows.size),
        "cutoff_hz": da.cutoff_hz,
        "absolute_torques": {
            "manus2": _error(fa.residual, ta),
            "urdf": _error(fr.residual @ TO_ABSOLUTE.T, tr @ TO_ABSOLUTE.T),
        },
        "motor_torques": {"manus2": _error(fa.residual @ to_motor.T, ta @ to_motor.T), "urdf": _error(fr.residual, tr)},
        "methods": {"manus2": fa.method, "urdf": fr.method},
    }
    f = fit(chain, CHAIN)  # as manus fit gives it
    report = f.report()
    return {
        "file": Path(path).name,
        "same_samples": same,
        "fit": {
            "method": f.method,
            "rel_error": f.rel_error,
            "params": {k: p["value"] for k, p in report["params"].items()},
            "std": {k: p["std"] for k, p in report["params"].items()},
        },
        "published": {**report["urdf_values"], **PUBLISHED_FRICTION},
    }


def compare(paths) -> dict:
    """Every recording compared, a line on stderr per recording with the time left."""
    import time

    runs, t0 = [], time.perf_counter()
    for k, p in enumerate(paths, 1):
        runs.append(compare_one(p))
        spent = time.perf_counter() - t0
        print(
            f"  [{k}/{len(paths)}] {Path(p).name}: {spent:.0f} s, about {spent / k * (len(paths) - k):.0f} s left",
            file=sys.stderr,
            flush=True,
        )
    names = list(runs[0]["fit"]["params"]) if runs else []
    median = {k: float(np.median([r["fit"]["params"][k] for r in runs])) for k in names}
    gain = (
        {
            k: float(np.mean([r["same_samples"][k]["manus2"] / r["same_samples"][k]["urdf"] for r in runs]))
            for k in ("absolute_torques", "motor_torques")
        }
        if runs
        else {}
    )
    return {
        "recordings": runs,
        "median": median,
        "published": runs[0]["published"] if runs else {},
        "error_ratio_manus2_over_urdf": gain,
    }


def render(r: dict) -> str:
    lines = [
        "torque error on the same samples (standstill kept), MANUS-2 absolute angles vs the URDF chain in relative "
        "coordinates:",
        f"{'file':24s} {'samples':>7s}  {'absolute torques':>22s}  {'motor torques':>22s}  methods",
    ]
    for x in r["recordings"]:
        s = x["same_samples"]
        a, m = s["absolute_torques"], s["motor_torques"]
        lines.append(
            f"{x['file']:24s} {s['samples']:7d}  {100 * a['manus2']:8.1f} % -> {100 * a['urdf']:5.1f} %  "
            f"{100 * m['manus2']:8.1f} % -> {100 * m['urdf']:5.1f} %  {s['methods']['manus2']}, {s['methods']['urdf']}"
        )
    g = r["error_ratio_manus2_over_urdf"]
    lines.append(
        f"MANUS-2's error over the chain's, mean: {g['absolute_torques']:.2f}x (absolute torques), "
        f"{g['motor_torques']:.2f}x (motor torques)"
    )
    lines.append("")
    lines.append("the chain's parameters as manus fit gives them (" + CHAIN + "), beside DFKI's model_2.0:")
    files = [x["file"].replace("A0_trajectory_", "")[:2] for x in r["recordings"]]
    lines.append(f"{'parameter':10s} {'DFKI':>9s} " + " ".join(f"{f:>9s}" for f in files) + f" {'median':>9s}")
    for k, med in r["median"].items():
        pub = r["published"].get(k)
        lines.append(
            f"{k:10s} {'' if pub is None else f'{pub:9.4g}':>9s} "
            + " ".join(f"{x['fit']['params'][k]:9.4g}" for x in r["recordings"])
            + f" {med:9.4g}"
        )
    lines.append(
        "methods: " + ", ".join(f"{f} {x['fit']['method']}" for f, x in zip(files, r["recordings"], strict=True))
    )
    return "\n".join(lines)


def main(argv=None) -> int:
    from manus.plants.errors import ManusError

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("recordings", nargs="+", help="DFKI exports (A0_trajectory_XX.csv)")
    p.add_argument("--json", action="store_true", help="one JSON object on stdout")
    args = p.parse_args(argv)
    try:
        r = compare(args.recordings)
    except ManusError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(r, indent=1) if args.json else render(r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
