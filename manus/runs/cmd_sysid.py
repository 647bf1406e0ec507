"""`manus sysid`: thesis §3.5–3.6 on the simulated arm — the three locked-joint free-oscillation
tests, the identified H11, H22, coupling a2, b and Fc against the simulated truth, and the
Cartesian inertia and damping ellipses and friction parallelograms over the workspace
(Figs. 3-18 to 3-23). How joints are locked and fitted: see `manus.experiments.sysid`."""

from __future__ import annotations

from manus.plants.errors import ManusError
from manus.runs.args import add_common
from manus.runs.progress import note
from manus.runs.text import table

NAME = "sysid"
HELP = "system identification of thesis §3.5 (locked-joint oscillations) and the Cartesian ellipses of §3.6"


def add_arguments(p) -> None:
    add_common(p)
    p.add_argument("--displacement", type=float, default=0.3, help="initial displacement from equilibrium [rad]")
    p.add_argument("--seconds", type=float, default=6.0, help="length of each test [s]")


def run(args) -> dict:
    from manus.experiments.sysid import study
    from manus.runs.figures import sysid as figures

    if not 0.02 <= args.displacement <= 1.0:
        raise ManusError(f"--displacement {args.displacement:g}: expected 0.02 to 1 rad")
    if args.seconds < 3:
        raise ManusError(f"--seconds {args.seconds:g}: a test needs at least 3 s to oscillate")
    note("three locked-joint oscillation tests ...")
    s = study(displacement=args.displacement, seconds=args.seconds)
    return s.result | {
        "figures": {
            "oscillations": figures.oscillations(s.traces, s.replays, args.out),
            "ellipses": figures.workspace(s.points, s.cartesian, args.out),
        }
    }


def render(r: dict) -> str:
    rows = [
        [k, f"{v['identified']:.4f}", f"{v['truth']:.4f}", f"{100 * v['rel_error']:+.2f} %"]
        for k, v in r["params"].items()
    ]
    c = r["cartesian"]["centre"]
    th = r["cartesian"]["thesis_centre"]
    lines = [
        table(rows, ["parameter", "identified", "truth", "error"]),
        f"largest error {100 * r['max_rel_error']:.2f} % ({'within' if r['within_5pct'] else 'NOT within'} 5 %)",
        f"at the workspace centre (r = {c['radius']:.3f} m): inertia eigenvalues "
        f"{c['inertia_eig'][0]:.2f}, {c['inertia_eig'][1]:.2f} kg (thesis ≈ {th['mass']:g}); damping x "
        f"{c['damping'][0][0]:.2f}, y {c['damping'][1][1]:.2f} N·s/m (thesis {th['damping_x']:g}, "
        f"{th['damping_y']:g}); friction {c['friction_range'][0]:.2f}–{c['friction_range'][1]:.2f} N",
    ]
    lines += [f"figure: {f}" for f in r["figures"].values()]
    return "\n".join(lines)
