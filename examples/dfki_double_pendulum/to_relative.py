"""The DFKI double pendulum's recordings in its own (relative) joint coordinates.

The recordings in ../shared/data/real/dfki_double_pendulum are converted to the MANUS-2 structure
(absolute link angles; the torques mapped by virtual work). They also carry what the rig recorded:
the relative elbow angle `q_rel2` and the motor torques `tau_motor1`, `tau_motor2`. This writes, for
each file given, a recording of the serial chain in `double_pendulum_a0.urdf` (beside this script):
q1 = the shoulder angle, q2 = the elbow angle relative to link 1, tau = the commanded motor torques
(the forces conjugate to those coordinates), with `# structure: urdf` and `# robot:` naming the URDF.
The driver-reported torques go along as `tau_meas1`, `tau_meas2`, mapped back to the motors.

    python examples/dfki_double_pendulum/to_relative.py \
        ../shared/data/real/dfki_double_pendulum/A0_trajectory_01.csv -o runs/out/dfki
    manus fit runs/out/dfki/A0_trajectory_01_relative.csv --model rigid,viscous,coulomb
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

URDF = Path(__file__).with_name("double_pendulum_a0.urdf")
NEEDS = ("q1", "q_rel2", "tau_motor1", "tau_motor2")


def relative(path: str | Path):
    """The recording at `path` (the absolute-angle export) as the URDF chain's recording."""
    from manus.plants import recording
    from manus.plants.errors import RecordingError

    rec = recording.read(path)
    cols = rec.columns()
    missing = [c for c in NEEDS if c not in cols]
    if missing:
        raise RecordingError(
            f"{path}: no column {', '.join(missing)}: not one of the DFKI double pendulum's "
            f"exports (they carry {', '.join(NEEDS)})"
        )
    meta = {k: v for k, v in rec.meta.items() if k in ("sample_rate_hz", "position_step", "source")}
    meta.update(
        structure="urdf",
        robot=str(URDF.absolute()),
        units="t s; q1 shoulder angle from the downward vertical, q2 elbow angle relative to link 1 [rad]; "
        "tau1, tau2 the commanded motor torques [N m]; tau_meas1, tau_meas2 the driver-reported ones",
    )
    extra = {}
    if "tau_meas1" in cols and "tau_meas2" in cols:  # mapped back: motor 1 = tau1 + tau2 of the absolute form
        extra = {"tau_meas1": cols["tau_meas1"] + cols["tau_meas2"], "tau_meas2": cols["tau_meas2"]}
    q = np.stack([cols["q1"], cols["q_rel2"]], 1)
    tau = np.stack([cols["tau_motor1"], cols["tau_motor2"]], 1)
    return recording.Recording(rec.t, q, tau, None, meta, extra, str(path))


def main(argv=None) -> int:
    from manus.plants import recording
    from manus.plants.errors import ManusError

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    p.add_argument("recordings", nargs="+", help="DFKI exports (A0_trajectory_XX.csv)")
    p.add_argument("-o", "--out", default="runs/out/dfki", help="folder for the relative recordings")
    args = p.parse_args(argv)
    try:
        for path in args.recordings:
            out = Path(args.out) / f"{Path(path).stem}_relative.csv"
            recording.write(relative(path), out)
            print(out)
    except ManusError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
