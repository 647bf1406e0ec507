"""`manus sysid`: thesis §3.5–3.6 on the simulated arm — the three locked-joint free-oscillation
tests, the identified H11, H22, coupling a2, b and Fc against the simulated truth, and the
Cartesian inertia and damping ellipses and friction parallelograms over the workspace
(Figs. 3-18 to 3-23). How joints are locked and fitted: see `runs/sysid.py`."""

from __future__ import annotations

import numpy as np

from manus.plants.errors import ManusError
from manus.runs.common import add_common, note, pyplot, save, table

NAME = "sysid"
HELP = "system identification of thesis §3.5 (locked-joint oscillations) and the Cartesian ellipses of §3.6"
TOLERANCE = 0.05  # the check: every identified parameter within 5 % of the truth
THESIS_CENTRE = {"mass": 1.0, "damping": 1.5, "damping_x": 1.6, "damping_y": 0.7}  # §3.7, Figs. 4-28/4-29


def add_arguments(p) -> None:
    add_common(p)
    p.add_argument("--displacement", type=float, default=0.3, help="initial displacement from equilibrium [rad]")
    p.add_argument("--seconds", type=float, default=6.0, help="length of each test [s]")


def run(args) -> dict:
    from manus.runs import sysid

    if not 0.02 <= args.displacement <= 1.0:
        raise ManusError(f"--displacement {args.displacement:g}: expected 0.02 to 1 rad")
    if args.seconds < 3:
        raise ManusError(f"--seconds {args.seconds:g}: a test needs at least 3 s to oscillate")
    note("three locked-joint oscillation tests ...")
    result = sysid.identify(displacement=args.displacement, seconds=args.seconds)
    traces = result.pop("traces")
    ident = {k: v["identified"] for k, v in result["params"].items()}
    replays = {t.name: sysid.replay(t, sysid.Fit(**result["fits"][t.name]), args.displacement, args.seconds)
               for t in sysid.lock_tests()}
    for t in sysid.lock_tests():  # output error of the fitted model: how well it replays the test
        result["fits"][t.name]["replay_rms"] = float(np.sqrt(np.mean(
            (replays[t.name].q[:, 0] - traces[t.name].q[:, t.joint]) ** 2)))
    points = sysid.workspace()
    cart = [sysid.cartesian(sysid.joint_angles(p), ident) for p in points]
    centre = sysid.cartesian(np.asarray(sysid.CENTRE), ident)
    errors = [abs(v["rel_error"]) for v in result["params"].values()]
    out = result | {
        "max_rel_error": max(errors), "within_5pct": bool(max(errors) <= TOLERANCE),
        "cartesian": {"centre": _describe(sysid.endpoint(sysid.CENTRE), centre), "thesis_centre": THESIS_CENTRE,
                      "by_radius": _by_radius(points, cart)},
        "figures": {"oscillations": _plot_oscillations(traces, replays, args.out),
                    "ellipses": _plot_workspace(points, cart, args.out)}}
    return out


def _describe(p, c: dict) -> dict:
    return {"position": p.tolist(), "radius": float(np.hypot(*p)), "inertia": c["inertia"].tolist(),
            "inertia_eig": np.linalg.eigvalsh(c["inertia"]).tolist(), "damping": c["damping"].tolist(),
            "damping_eig": np.linalg.eigvalsh(c["damping"]).tolist(),
            "friction_range": list(_friction_range(c["friction"]))}


def _friction_range(corners: np.ndarray) -> tuple[float, float]:
    """Smallest and largest distance from the centre to the parallelogram's boundary [N]."""
    edges = np.roll(corners, -1, 0) - corners
    normals = np.stack([edges[:, 1], -edges[:, 0]], 1) / np.linalg.norm(edges, axis=1, keepdims=True)
    return float(np.min(np.abs(np.sum(normals * corners, 1)))), float(np.max(np.linalg.norm(corners, axis=1)))


def _by_radius(points, cart) -> list[dict]:
    """Each parameter's least and largest value along the column through the centre: they
    depend on the distance from the motor axis alone (§3.6)."""
    from manus.runs.sysid import CENTRE, endpoint

    on_axis = np.flatnonzero(np.isclose(points[:, 0], endpoint(CENTRE)[0]))
    return [{"radius": float(np.hypot(*points[i])), "inertia": np.linalg.eigvalsh(cart[i]["inertia"]).tolist(),
             "damping": np.linalg.eigvalsh(cart[i]["damping"]).tolist(), "friction": list(_friction_range(cart[i]["friction"]))}
            for i in on_axis]


def _plot_oscillations(traces: dict, replays: dict, out) -> str:
    """Figs. 3-18 to 3-20: each test's recording and the fitted model run through it."""
    from manus.runs.sysid import lock_tests

    plt = pyplot()
    fig, axes = plt.subplots(1, len(traces), figsize=(4.2 * len(traces), 3.2), squeeze=False)
    for ax, test in zip(axes[0], lock_tests()):
        traj, model = traces[test.name], replays[test.name]
        ax.plot(traj.t, traj.q[:, test.joint], lw=0.9, label=f"q{test.joint + 1}, simulated arm")
        ax.plot(model.t, model.q[:, 0], "--", lw=0.9, label="fitted 1-DOF model")
        ax.set(xlabel="t [s]", ylabel=f"q{test.joint + 1} [rad]", title=test.name)
        ax.legend(fontsize=7)
    fig.tight_layout()
    return save(fig, out, "sysid_oscillations.png")


def _plot_workspace(points, cart, out) -> str:
    """Figs. 3-21 to 3-23: ellipses and parallelograms over the workspace, drawn to scale per panel."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 5))
    theta = np.linspace(0, 2 * np.pi, 80)
    unit = np.stack([np.cos(theta), np.sin(theta)])
    spacing = 0.5 * np.min(np.diff(np.unique(points[:, 0])))
    for ax, key, title in zip(axes, ("inertia", "damping", "friction"),
                              ("inertia ellipses [kg]", "viscous damping ellipses [N·s/m]",
                               "Coulomb friction parallelograms [N]")):
        size = max(np.abs(c[key]).max() for c in cart)
        for p, c in zip(points, cart):
            shape = (c[key] @ unit).T if key != "friction" else np.vstack([c[key], c[key][:1]])
            ax.plot(*(p + spacing * shape / size).T, lw=0.9)
            ax.plot(*p, "k.", ms=2)
        for r in np.linspace(*np.percentile(np.hypot(*points.T), [0, 100]), 4):  # arcs of constant radius
            a = np.linspace(0.2, np.pi - 0.2, 100)
            ax.plot(r * np.cos(a), r * np.sin(a), "k:", lw=0.5)
        ax.add_patch(plt.Circle((0, 0), 0.05, fill=False, lw=1.5))  # the actuators
        lo, hi = points.min(0) - spacing, points.max(0) + spacing
        ax.add_patch(plt.Rectangle(lo, *(hi - lo), fill=False, lw=1.2))  # the workspace
        ax.set(aspect="equal", xlabel="x [m]", ylabel="y [m]", title=title, xlim=(lo[0] - 0.05, hi[0] + 0.05),
               ylim=(-0.08, hi[1] + 0.05))
    fig.tight_layout()
    return save(fig, out, "sysid_cartesian.png")


def render(r: dict) -> str:
    rows = [[k, f"{v['identified']:.4f}", f"{v['truth']:.4f}", f"{100 * v['rel_error']:+.2f} %"]
            for k, v in r["params"].items()]
    c = r["cartesian"]["centre"]
    th = r["cartesian"]["thesis_centre"]
    lines = [table(rows, ["parameter", "identified", "truth", "error"]),
             f"largest error {100 * r['max_rel_error']:.2f} % ({'within' if r['within_5pct'] else 'NOT within'} 5 %)",
             f"at the workspace centre (r = {c['radius']:.3f} m): inertia eigenvalues "
             f"{c['inertia_eig'][0]:.2f}, {c['inertia_eig'][1]:.2f} kg (thesis ≈ {th['mass']:g}); damping x "
             f"{c['damping'][0][0]:.2f}, y {c['damping'][1][1]:.2f} N·s/m (thesis {th['damping_x']:g}, "
             f"{th['damping_y']:g}); friction {c['friction_range'][0]:.2f}–{c['friction_range'][1]:.2f} N"]
    lines += [f"figure: {f}" for f in r["figures"].values()]
    return "\n".join(lines)

