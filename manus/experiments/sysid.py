"""System identification as in thesis §3.5, on the simulated MANUS-2 arm, and the Cartesian
inertia, damping and friction of §3.6 (Figs. 3-21 to 3-23).

**The tests.** The motors act as a virtual spring τ = K (q_d − q), K = 10 N·m/rad (eq. 3.5), on
one coordinate while another is locked; the arm is displaced and released, and the free
oscillation identifies the one-coordinate model H ẍ + b ẋ + F sgn(ẋ) + K x = K x_d
(eqs. 3.7, 3.8, 3.10):

1. elbow locked in the absolute frame (q2 fixed): H11, b1, Fc1 (§3.5.2);
2. shoulder locked (q1 fixed): H22, b2, Fc2 (§3.5.3);
3. elbow locked to the upper arm, q2 − q1 = 0.4554 rad (§3.5.4): H11* = H11 + H22 +
   2 a2 cos(0.4554) with b* = b1 + b2, F* = Fc1 + Fc2; then the coupling a2 = m2 l1 c2 by eq. 3.12.

**How a joint is locked here.** The simulator has no pins, so the lock is a stiff servo on the
locked coordinate φ = c·q, driven through the same motors: τ_lock = −(K_L (φ − φ_d) + B_L φ̇̂) cᵀ
with K_L = 1000 N·m/rad and B_L = 5 N·m·s/rad on the filtered first-difference velocity (stable
with margin ≥ 2.8 for every locked inertia, by the sampled linear analysis of
`manus.experiments.stability.linear`). For the relative lock the pair (+τ, −τ) is what a pin between the
links would exert; it cancels in τ1 + τ2, the torque the third test reads. The lock yields by
about a milliradian under the coupling torques: its share of the identified inertia is below
0.5 %.

**The fit.** Equation error, linear least squares: the recorded position is differentiated
offline (zero-phase, `manus.estimators.offline`), the commanded torque is centred on the sample
(the zero-order hold applies τ_k over [t_k, t_k + T): (τ_{k−1} + τ_k)/2) and low-passed alike,
and samples near a velocity reversal (where sgn(ẋ) is not defined and the filter smears the
friction's jump) are left out.

Units: rad, N·m, kg·m²; Cartesian: m, N, kg, N·s/m. Joint angles are absolute.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from manus.adaptive.controllers import LockedSpring
from manus.estimators.base import FilteredFirstDifference
from manus.estimators.offline import differentiate, edge, lowpass

LINKS = (0.40533, 0.48793)  # m, upper arm and forearm (two-bar equivalent of the linkage)
CENTRE = (0.464, 2.409)  # rad, the workspace centre (0.508 m from the motor axis)
RELATIVE_LOCK = 0.4554  # rad, q2 − q1 in the third test (eq. 3.9)
SPRING = 10.0  # N·m/rad, eq. 3.5
TOLERANCE = 0.05  # the check: every identified parameter within 5 % of the truth
THESIS_CENTRE = {"mass": 1.0, "damping": 1.5, "damping_x": 1.6, "damping_y": 0.7}  # §3.7, Figs. 4-28/4-29


class LockTest(NamedTuple):
    """One locked-joint experiment: the spring's joint, the lock c, the motion direction d
    (c·d = 0; the free coordinate is q_joint and its generalized force τ·d), rest and release
    positions."""

    name: str
    joint: int
    lock: tuple[float, float]
    direction: tuple[float, float]
    equilibrium: tuple[float, float]


def lock_tests() -> tuple[LockTest, ...]:
    q1, q2 = CENTRE
    return (
        LockTest("elbow locked", 0, (0.0, 1.0), (1.0, 0.0), (q1, q2)),
        LockTest("shoulder locked", 1, (1.0, 0.0), (0.0, 1.0), (q1, q2)),
        LockTest("relative lock", 0, (-1.0, 1.0), (1.0, 1.0), (q1, q1 + RELATIVE_LOCK)),
    )


class Fit(NamedTuple):
    inertia: float  # kg·m²
    damping: float  # N·m·s/rad
    friction: float  # N·m
    rel_error: float  # ‖y − Φθ‖ / ‖y‖ over the samples used
    samples: int


def fit_oscillation(t, x, tau, dt: float, cutoff_hz: float = 20.0, min_speed: float = 0.1, after: float = 0.0) -> Fit:
    """(H, b, F) of H ẍ + b ẋ + F sgn(ẋ) = τ from a free oscillation: x (T,) measured, τ (T,)
    the generalized force commanded at each tick (held until the next)."""
    _, xd, xdd = differentiate(np.asarray(x, float), dt, cutoff_hz)
    tau = np.asarray(tau, float)
    centred = 0.5 * (tau + np.concatenate([tau[:1], tau[:-1]]))
    y = lowpass(centred, dt, cutoff_hz)
    e = edge(dt, cutoff_hz)
    use = (np.abs(xd) > min_speed) & (np.asarray(t) > after + e * dt)
    use[:e], use[-e:] = False, False
    Phi = np.stack([xdd, xd, np.sign(xd)], 1)[use]
    theta, *_ = np.linalg.lstsq(Phi, y[use], rcond=None)
    rel = float(np.linalg.norm(y[use] - Phi @ theta) / np.linalg.norm(y[use]))
    inertia, damping, friction = (float(x) for x in theta)
    return Fit(inertia, damping, friction, rel, int(use.sum()))


def simulate_test(
    test: LockTest, params: dict | None = None, displacement: float = 0.3, seconds: float = 6.0, release: float = 0.5
):
    """Run one locked test on the MANUS-2 arm (rigid, viscous, coulomb; the thesis's actuator
    chain and encoder): at rest displaced by `displacement` rad along d, released (the spring's
    set point steps back) at `release` s. Returns the closed-loop trajectory."""
    from manus.plants import Manus2, Model, Simulator
    from manus.plants.closed_loop import simulate
    from manus.plants.references import Step

    plant = Simulator(Model(Manus2(), "rigid,viscous,coulomb"), params)
    eq = np.asarray(test.equilibrium)
    start = eq + displacement * np.asarray(test.direction)
    ctrl = LockedSpring(
        jnp.eye(2)[test.joint], jnp.asarray(test.lock), stiffness=SPRING, estimator=FilteredFirstDifference(dt=plant.dt)
    )
    return simulate(plant, ctrl, Step(start, eq, release), seconds), plant


def replay(test: LockTest, fit: Fit, displacement: float = 0.3, seconds: float = 6.0, release: float = 0.5):
    """The fitted one-coordinate model (eqs. 3.7, 3.8, 3.10: an axis with inertia H, b and F
    under the same spring) through the same test: compare with the recording (Figs. 3-18 to 3-20)."""
    from manus.adaptive.impedance import Impedance
    from manus.plants import Axis, Model, Simulator
    from manus.plants.closed_loop import simulate
    from manus.plants.references import Step

    plant = Simulator(
        Model(Axis(), "rigid,viscous,coulomb"), {"M1": fit.inertia, "b1": fit.damping, "Fc1": fit.friction}
    )
    x0 = test.equilibrium[test.joint]
    return simulate(plant, Impedance(SPRING, 0.0, n_joints=1), Step([x0 + displacement], [x0], release), seconds)


def identify(params: dict | None = None, displacement: float = 0.3, seconds: float = 6.0) -> dict:
    """The three tests, the fits, the coupling a2 (eq. 3.12), and each against the truth."""
    fits, traces = {}, {}
    for test in lock_tests():
        traj, plant = simulate_test(test, params, displacement, seconds)
        tau = np.asarray(traj.tau) @ np.asarray(test.direction)
        fits[test.name] = fit_oscillation(traj.t, traj.q[:, test.joint], tau, plant.dt, after=0.5)
        traces[test.name] = traj
    truth = {k: float(v) for k, v in plant.params.items()}
    one, two, rel = fits["elbow locked"], fits["shoulder locked"], fits["relative lock"]
    a2 = (rel.inertia - (one.inertia + two.inertia)) / (2 * math.cos(RELATIVE_LOCK))
    found = {
        "a1": one.inertia,
        "b1": one.damping,
        "Fc1": one.friction,
        "a3": two.inertia,
        "b2": two.damping,
        "Fc2": two.friction,
        "H11*": rel.inertia,
        "b*": rel.damping,
        "F*": rel.friction,
        "a2": a2,
    }
    true = {
        "a1": truth["a1"],
        "b1": truth["b1"],
        "Fc1": truth["Fc1"],
        "a3": truth["a3"],
        "b2": truth["b2"],
        "Fc2": truth["Fc2"],
        "H11*": truth["a1"] + truth["a3"] + 2 * truth["a2"] * math.cos(RELATIVE_LOCK),
        "b*": truth["b1"] + truth["b2"],
        "F*": truth["Fc1"] + truth["Fc2"],
        "a2": truth["a2"],
    }
    return {
        "params": {k: {"identified": found[k], "truth": true[k], "rel_error": found[k] / true[k] - 1} for k in found},
        "fits": {name: f._asdict() for name, f in fits.items()},
        "traces": traces,
    }


# -- Cartesian parameters (§3.6) ---------------------------------------------------------------
def endpoint(q) -> np.ndarray:
    """x = l1 cos q1 + l2 cos q2, y = l1 sin q1 + l2 sin q2 (absolute angles)."""
    l1, l2 = LINKS
    return np.array([l1 * np.cos(q[0]) + l2 * np.cos(q[1]), l1 * np.sin(q[0]) + l2 * np.sin(q[1])])


def jacobian(q) -> np.ndarray:
    l1, l2 = LINKS
    return np.array([[-l1 * np.sin(q[0]), -l2 * np.sin(q[1])], [l1 * np.cos(q[0]), l2 * np.cos(q[1])]])


def joint_angles(p) -> np.ndarray:
    """Inverse kinematics with the elbow as in the workspace (0 < q2 − q1 < π)."""
    l1, l2 = LINKS
    r2 = float(p[0] ** 2 + p[1] ** 2)
    c = (r2 - l1 * l1 - l2 * l2) / (2 * l1 * l2)
    if abs(c) > 1:
        raise ValueError(f"({p[0]:.3f}, {p[1]:.3f}) m is out of reach")
    rel = math.acos(c)
    q1 = math.atan2(p[1], p[0]) - math.atan2(l2 * math.sin(rel), l1 + l2 * math.cos(rel))
    return np.array([q1, q1 + rel])


def cartesian(q, p: dict) -> dict:
    """At joint angles q: the endpoint inertia J⁻ᵀ H J⁻¹ [kg], damping J⁻ᵀ B J⁻¹ [N·s/m] and
    the corners of the friction parallelogram {J⁻ᵀ τ : |τ_i| ≤ Fc_i} [N]."""
    Ji = np.linalg.inv(jacobian(q))
    c = math.cos(q[1] - q[0])
    H = np.array([[p["a1"], p["a2"] * c], [p["a2"] * c, p["a3"]]])
    corners = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * np.array([p["Fc1"], p["Fc2"]])
    return {"inertia": Ji.T @ H @ Ji, "damping": Ji.T @ np.diag([p["b1"], p["b2"]]) @ Ji, "friction": corners @ Ji}


def workspace(nx: int = 5, ny: int = 5, half_x: float = 0.25, half_y: float = 0.2) -> np.ndarray:
    """Endpoint positions (nx·ny, 2) on a grid around the workspace centre."""
    centre = endpoint(CENTRE)
    xs, ys = np.linspace(-half_x, half_x, nx), np.linspace(-half_y, half_y, ny)
    return np.array([centre + [x, y] for y in ys for x in xs])


# -- the whole study -----------------------------------------------------------------------------
class Study(NamedTuple):
    """`study`'s result: the JSON-ready figures, and what the figures are drawn from."""

    result: dict
    traces: dict  # test name -> the closed-loop trajectory of the simulated arm
    replays: dict  # test name -> the fitted one-coordinate model through the same test
    points: np.ndarray  # endpoint positions over the workspace (N, 2)
    cartesian: list  # `cartesian` at each point


def study(displacement: float = 0.3, seconds: float = 6.0) -> Study:
    """The three tests and their fits against the truth (`identify`), each fitted model replayed
    through its test (`replay_rms`: its output error), and the Cartesian parameters over the
    workspace and at its centre against the thesis's."""
    result = identify(displacement=displacement, seconds=seconds)
    traces = result.pop("traces")
    ident = {k: v["identified"] for k, v in result["params"].items()}
    replays = {t.name: replay(t, Fit(**result["fits"][t.name]), displacement, seconds) for t in lock_tests()}
    for t in lock_tests():  # output error of the fitted model: how well it replays the test
        result["fits"][t.name]["replay_rms"] = float(
            np.sqrt(np.mean((replays[t.name].q[:, 0] - traces[t.name].q[:, t.joint]) ** 2))
        )
    points = workspace()
    cart = [cartesian(joint_angles(p), ident) for p in points]
    centre = cartesian(np.asarray(CENTRE), ident)
    errors = [abs(v["rel_error"]) for v in result["params"].values()]
    result = result | {
        "max_rel_error": max(errors),
        "within_5pct": bool(max(errors) <= TOLERANCE),
        "cartesian": {
            "centre": describe(endpoint(CENTRE), centre),
            "thesis_centre": THESIS_CENTRE,
            "by_radius": by_radius(points, cart),
        },
    }
    return Study(result, traces, replays, points, cart)


def describe(p, c: dict) -> dict:
    """The Cartesian parameters `c` at endpoint `p`, JSON-ready, with their eigenvalues."""
    return {
        "position": p.tolist(),
        "radius": float(np.hypot(*p)),
        "inertia": c["inertia"].tolist(),
        "inertia_eig": np.linalg.eigvalsh(c["inertia"]).tolist(),
        "damping": c["damping"].tolist(),
        "damping_eig": np.linalg.eigvalsh(c["damping"]).tolist(),
        "friction_range": list(friction_range(c["friction"])),
    }


def friction_range(corners: np.ndarray) -> tuple[float, float]:
    """Smallest and largest distance from the centre to the parallelogram's boundary [N]."""
    edges = np.roll(corners, -1, 0) - corners
    normals = np.stack([edges[:, 1], -edges[:, 0]], 1) / np.linalg.norm(edges, axis=1, keepdims=True)
    return float(np.min(np.abs(np.sum(normals * corners, 1)))), float(np.max(np.linalg.norm(corners, axis=1)))


def by_radius(points, cart) -> list[dict]:
    """Each parameter's least and largest value along the column through the centre: they
    depend on the distance from the motor axis alone (§3.6)."""
    on_axis = np.flatnonzero(np.isclose(points[:, 0], endpoint(CENTRE)[0]))
    return [
        {
            "radius": float(np.hypot(*points[i])),
            "inertia": np.linalg.eigvalsh(cart[i]["inertia"]).tolist(),
            "damping": np.linalg.eigvalsh(cart[i]["damping"]).tolist(),
            "friction": list(friction_range(cart[i]["friction"])),
        }
        for i in on_axis
    ]
