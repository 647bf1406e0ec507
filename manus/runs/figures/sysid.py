"""Figures of the system identification of thesis §3.5–3.6: the locked-joint oscillations with
the fitted models replayed (Figs. 3-18 to 3-20), and the Cartesian inertia and damping ellipses
and friction parallelograms over the workspace (Figs. 3-21 to 3-23). `draw_*` builds a figure,
the other functions write it."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from manus.runs.figures.common import panels, save, styled, tidy

if TYPE_CHECKING:
    from matplotlib.figure import Figure


@styled
def draw_oscillations(traces: dict, replays: dict) -> Figure:
    """Figs. 3-18 to 3-20: each test's recording and the fitted model run through it."""
    from manus.experiments.sysid import lock_tests

    fig, axes = panels(1, len(traces), (4.4, 3.2), "locked-joint oscillations and the fitted 1-DOF models replayed")
    for ax, test in zip(axes[0], lock_tests(), strict=True):
        traj, model = traces[test.name], replays[test.name]
        ax.plot(traj.t, traj.q[:, test.joint], lw=0.9, label=f"q{test.joint + 1}, simulated arm")
        ax.plot(model.t, model.q[:, 0], "--", lw=0.9, label="fitted 1-DOF model")
        ax.set(xlabel="t [s]", ylabel=f"q{test.joint + 1} [rad]")
        ax.set_title(test.name, loc="left")
        ax.legend()
    tidy(axes)
    return fig


def oscillations(traces: dict, replays: dict, out) -> str:
    """`draw_oscillations` written as `out/sysid_oscillations.png`; returns its path."""
    return save(draw_oscillations(traces, replays), out, "sysid_oscillations.png")


@styled
def draw_workspace(points: np.ndarray, cart) -> Figure:
    """Figs. 3-21 to 3-23: ellipses and parallelograms over the workspace, drawn to scale per panel
    (the largest shape of a panel fills half the spacing of the points)."""
    from matplotlib.patches import Circle, Rectangle

    fig, axes = panels(
        1,
        3,
        (5.0, 4.6),
        "the arm's Cartesian parameters over the workspace",
        note="Each shape drawn at its point, scaled per panel: the largest fills half the spacing of the points. "
        "Dotted: arcs of constant radius; circle: the actuators; rectangle: the workspace.",
    )
    theta = np.linspace(0, 2 * np.pi, 80)
    unit = np.stack([np.cos(theta), np.sin(theta)])
    spacing = 0.5 * np.min(np.diff(np.unique(points[:, 0])))
    for ax, key, title in zip(
        axes[0],
        ("inertia", "damping", "friction"),
        ("inertia ellipses [kg]", "viscous damping ellipses [N·s/m]", "Coulomb friction parallelograms [N]"),
        strict=True,
    ):
        size = max(np.abs(c[key]).max() for c in cart)
        for p, c in zip(points, cart, strict=True):
            shape = (c[key] @ unit).T if key != "friction" else np.vstack([c[key], c[key][:1]])
            ax.plot(*(p + spacing * shape / size).T, lw=0.9)
            ax.plot(*p, "k.", ms=2)
        smallest, largest = np.percentile(np.hypot(*points.T), [0, 100])
        for r in np.linspace(smallest, largest, 4):  # arcs of constant radius
            a = np.linspace(0.2, np.pi - 0.2, 100)
            ax.plot(r * np.cos(a), r * np.sin(a), "k:", lw=0.5)
        ax.add_patch(Circle((0, 0), 0.05, fill=False, lw=1.5))  # the actuators
        lo, hi = points.min(0) - spacing, points.max(0) + spacing
        ax.add_patch(Rectangle(lo, *(hi - lo), fill=False, lw=1.2))  # the workspace
        ax.set(
            aspect="equal",
            xlabel="x [m]",
            ylabel="y [m]",
            xlim=(lo[0] - 0.05, hi[0] + 0.05),
            ylim=(-0.08, hi[1] + 0.05),
        )
        ax.set_title(title, loc="left")
    tidy(axes)
    return fig


def workspace(points: np.ndarray, cart, out) -> str:
    """`draw_workspace` written as `out/sysid_cartesian.png`; returns its path."""
    return save(draw_workspace(points, cart), out, "sysid_cartesian.png")
