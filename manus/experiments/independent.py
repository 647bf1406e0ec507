"""A second simulator, written from the equations and not from `manus.plants`: recordings that
manus's own simulator did not make, to calibrate diagnose against (`manus bench diagnose
--calibrate --simulator independent`).

What it does differently from `manus.plants.simulator`, on purpose:
- the thesis arm from Lagrange's equations in absolute angles, written out here (M11 = a1, the
  coupling a2 cos(q2 − q1), M22 = a3; the velocity terms ∓a2 sin(q2 − q1) q̇²), and a linear axis;
- friction regularized as most other simulators do it, Fc tanh(q̇/ε) (Drake's stiction tolerance,
  MuJoCo's soft friction loss): a joint held against its friction creeps at a speed of order ε
  instead of sticking, so at a hold its friction is anything between ±Fc;
- classical RK4 with sub-steps short enough for that friction's slope at rest;
- a PD loop on a 30 Hz filtered first difference of the quantized encoder (thesis §3.4), its
  command held over each period; quintic reaching moves with rests, a multi-sine reference, and
  open-loop torque doublets of its own timing;
- the recording is written as a CSV file and read back by `manus.plants.recording.read`, as a
  user's file would be.

The conditions follow the calibration's (`manus.experiments.calibration`): arm or prismatic axis,
three excitations, torque exact / with white noise of 10–30 % of its RMS / with an unrecorded
disturbance of 3–8 % low-passed at 1–5 Hz, hold stated or not; rates 1 kHz, 500 Hz and 200 Hz.
A hidden effect's torque RMS is `amplitude` of the recorded torque's (measured on a first run,
as the calibration does); a delay is drawn, not sized: whole samples, 1–3 ms at 1 kHz and faster,
else one or two samples (the calibration sizes its delays to the same 5 %; this one keeps the
harder draw of its first version, whose figures the README quotes). No compliance (the shaft is rigid here).
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from scipy import signal

from manus.experiments.calibration import AMPLITUDE, Case
from manus.experiments.sizing import rms

RATES = (1000, 500, 200)
A1, A2, A3 = 0.349, 0.241, 0.246  # kg m²: M11, the coupling, M22 (thesis §3.5.5)
M_MIN = 0.051  # the smallest eigenvalue of the arm's mass matrix (at cos = 1) [kg m²]
ARM: dict[str, Any] = dict(
    n=2,
    b=(0.161, 0.107),
    fc=(0.099, 0.139),
    centre=(0.464, 2.409),
    step=2 * math.pi / 131072,
    swing=0.3,
    kp=30.0,
    kd=1.0,
    pulse=(1.2, 0.7),
    pulse_s=(0.04, 0.2),
    vs=0.05,
    eps=1e-3,
)
AXIS: dict[str, Any] = dict(
    n=1,
    m=2.5,
    b=(15.0,),
    fc=(5.0,),
    centre=(0.0,),
    step=1e-6,
    swing=0.05,
    kp=1500.0,
    kd=50.0,
    pulse=(25.0,),
    pulse_s=(0.02, 0.08),
    vs=0.02,
    eps=1e-4,
)
EFFECTS = ("rigid", "viscous", "coulomb", "stribeck", "asymmetry", "offset", "gravity", "spring", "cogging", "delay")
NOMINAL = ("rigid", "viscous", "coulomb")


def _torques(cfg: dict, p: dict, q, v):
    """Everything but inertia: friction (regularized), the hidden loads."""
    slip = jnp.tanh(v / cfg["eps"])
    t = p["b"] * v + p["fc"] * slip + p["dfs"] * jnp.exp(-((v / cfg["vs"]) ** 2)) * slip
    t = t + p["db"] * jnp.abs(v) + p["off"] + p["k"] * (q - p["q0"])
    t = t + p["gc"] * jnp.cos(q) + p["gs"] * jnp.sin(q)
    return t + p["ca"] * jnp.sin(p["order"] * q) + p["cb"] * jnp.cos(p["order"] * q)


def _acceleration(arm: bool, cfg: dict, p: dict, q, v, tau):
    rhs = tau - _torques(cfg, p, q, v)
    if not arm:
        return rhs / cfg["m"]
    s, c = jnp.sin(q[1] - q[0]), jnp.cos(q[1] - q[0])
    r1, r2 = rhs[0] + A2 * s * v[1] ** 2, rhs[1] - A2 * s * v[0] ** 2
    det = A1 * A3 - (A2 * c) ** 2
    return jnp.stack([(A3 * r1 - A2 * c * r2) / det, (A1 * r2 - A2 * c * r1) / det])


def _run(arm: bool, p: dict, ref, pulses, disturbance, rate: int, delay: int, substeps: int, closed: bool):
    cfg = ARM if arm else AXIS
    n, dt = cfg["n"], 1.0 / rate
    h = dt / substeps
    smooth = 1 - math.exp(-2 * math.pi * 30.0 * dt)

    def rk4(x, tau):
        def f(x):
            return jnp.concatenate([x[n:], _acceleration(arm, cfg, p, x[:n], x[n:], tau)])

        k1 = f(x)
        k2 = f(x + 0.5 * h * k1)
        k3 = f(x + 0.5 * h * k2)
        k4 = f(x + h * k3)
        return x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)

    def sample(carry, inputs):
        x, before, speed, queue = carry
        r, pulse, d = inputs
        measured = jnp.round(x[:n] / cfg["step"]) * cfg["step"]
        speed = speed + smooth * ((measured - before) / dt - speed)
        u = cfg["kp"] * (r[:n] - measured) + cfg["kd"] * (r[n:] - speed) if closed else pulse
        queue = jnp.concatenate([queue[1:], u[None]], axis=0)  # the command `delay` samples late
        x = jax.lax.fori_loop(0, substeps, lambda i, x: rk4(x, queue[0] + d), x)
        return (x, measured, speed, queue), (measured, u)

    x0 = jnp.concatenate([ref[0, :n], jnp.zeros(n)])
    first = jnp.round(x0[:n] / cfg["step"]) * cfg["step"]
    _, (q, u) = jax.lax.scan(sample, (x0, first, jnp.zeros(n), jnp.zeros((delay + 1, n))), (ref, pulses, disturbance))
    return q, u


_compiled = jax.jit(_run, static_argnames=("arm", "rate", "delay", "substeps", "closed"))


def simulate(
    arm: bool,
    p: dict,
    ref: np.ndarray,
    pulses: np.ndarray,
    disturbance: np.ndarray,
    rate: int,
    delay: int = 0,
    closed: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """(measured positions, command), each (steps, n). RK4 sub-steps keep h·(Fc + dFs)/(ε·M) ≤ 1/2
    (rounded up to a power of two: few compilations)."""
    cfg = ARM if arm else AXIS
    stiff = float(np.max(np.abs(p["fc"]) + np.abs(p["dfs"]))) / (cfg["eps"] * (M_MIN if arm else cfg["m"]))
    substeps = max(8, 2 ** int(np.ceil(np.log2(max(2 * stiff / rate, 1.0)))))
    with jax.enable_x64(True):
        args = [{k: jnp.asarray(v, float) for k, v in p.items()}] + [
            jnp.asarray(x, float) for x in (ref, pulses, disturbance)
        ]
        q, u = _compiled(arm, *args, rate=rate, delay=delay, substeps=substeps, closed=closed)
        return np.asarray(q), np.asarray(u)


def reference(cfg: dict, excitation: str, rate: int, steps: int, rng) -> np.ndarray:
    """Positions and speeds (steps, 2n) the loop follows: a multi-sine of four tones per joint
    (0.15–1.5 Hz, faded in over a second) or quintic moves of 0.5–1.2 s with rests of 0.2–0.8 s."""
    n, dt = cfg["n"], 1.0 / rate
    t = np.arange(steps) * dt
    q = np.tile(np.asarray(cfg["centre"], float), (steps, 1))
    if excitation == "multisine":
        for j in range(n):
            a = rng.uniform(0.3, 1.0, 4)
            a *= cfg["swing"] / a.sum()
            tones = a * np.sin(2 * np.pi * rng.uniform(0.15, 1.5, 4) * t[:, None] + rng.uniform(0, 2 * np.pi, 4))
            q[:, j] += np.clip(t, 0, 1) * tones.sum(1)
    elif excitation == "reaching":
        now, k = q[0].copy(), int(0.4 * rate)
        while k < steps:
            target = np.asarray(cfg["centre"]) + rng.uniform(-cfg["swing"], cfg["swing"], n)
            m = int(rng.uniform(0.5, 1.2) * rate)
            x = np.linspace(0, 1, m)[:, None]
            q[k : k + m] = (now + (10 * x**3 - 15 * x**4 + 6 * x**5) * (target - now))[: steps - k]
            q[k + m :] = target
            now, k = target, k + m + int(rng.uniform(0.2, 0.8) * rate)
    return np.concatenate([q, np.gradient(q, dt, axis=0)], axis=1)


def pulses(cfg: dict, rate: int, steps: int, rng) -> np.ndarray:
    """Open-loop torque doublets +A, −A (twice as long), +A of random sign, level (50–100 %) and
    length, with rests of 0–0.4 s."""
    u = np.zeros((steps, cfg["n"]))
    for j in range(cfg["n"]):
        k = int(rng.integers(0, int(0.1 * rate) + 1))
        while k < steps:
            a = cfg["pulse"][j] * rng.uniform(0.5, 1.0) * rng.choice([-1.0, 1.0])
            length = max(1, int(rng.uniform(*cfg["pulse_s"]) * rate))
            for level, m in ((a, length), (-a, 2 * length), (a, length)):
                u[k : k + m, j] = level
                k += m
            k += int(rng.uniform(0.0, 0.4) * rate)
    return u


def _unit(hidden: str, cfg: dict, p: dict, q: np.ndarray, v: np.ndarray, phase: float) -> np.ndarray:
    """The hidden effect's torque per unit of its size along a motion, (steps, n)."""
    return {
        "stribeck": lambda: np.exp(-((v / cfg["vs"]) ** 2)) * np.tanh(v / cfg["eps"]),
        "asymmetry": lambda: np.abs(v),
        "offset": lambda: np.ones_like(q),
        "spring": lambda: q - p["q0"],
        "gravity": lambda: np.cos(q + phase),
        "cogging": lambda: np.sin(p["order"] * q + phase),
    }[hidden]()


def _set(hidden: str, p: dict, size: np.ndarray, phase: float) -> None:
    if hidden == "gravity":  # g cos(q + φ) = g cos φ cos q − g sin φ sin q
        p["gc"], p["gs"] = size * np.cos(phase), -size * np.sin(phase)
    elif hidden == "cogging":
        p["ca"], p["cb"] = size * np.cos(phase), size * np.sin(phase)
    else:
        p[{"stribeck": "dfs", "asymmetry": "db", "offset": "off", "spring": "k"}[hidden]] = size


def case(seed: int, hidden: str | None = None, rates: tuple = RATES, amplitude: float = AMPLITUDE, **overrides) -> Case:
    """Recording `seed` of the independent simulator: nothing hidden, or `hidden` (one of
    `EFFECTS`) left out of the start model. Keyword overrides fix condition values (structure,
    rate, excitation, torque, hold)."""
    if hidden is not None and hidden not in EFFECTS:
        raise ValueError(f"the independent simulator hides one of {', '.join(EFFECTS)} (not {hidden})")
    t_start = time.perf_counter()
    rng = np.random.default_rng([seed, 2026])
    drawn = {
        "structure": str(rng.choice(["arm", "axis"])),
        "rate": int(rng.choice(rates)),
        "excitation": str(rng.choice(["multisine", "reaching", "steps"])),
        "torque": str(rng.choice(["exact", "white", "coloured"])),
        "hold": str(rng.choice(["stated", "not stated"])),
    }
    if hidden == "gravity":
        drawn["structure"] = "arm"
    unknown = set(overrides) - set(drawn)
    if unknown:
        raise ValueError(f"unknown condition key(s) {sorted(unknown)}: {', '.join(drawn)}")
    drawn.update(overrides)
    structure, rate, excitation, torque, hold = (
        drawn[k] for k in ("structure", "rate", "excitation", "torque", "hold")
    )
    arm = structure == "arm"
    cfg = ARM if arm else AXIS
    n = cfg["n"]
    steps = int((12.0 if rate >= 1000 else 20.0) * rate)
    ref = reference(cfg, excitation, rate, steps, rng)
    push = pulses(cfg, rate, steps, rng) if excitation == "steps" else np.zeros((steps, n))
    zero = np.zeros(n)
    p = dict(
        b=np.array(cfg["b"]),
        fc=np.array(cfg["fc"]),
        dfs=zero,
        db=zero,
        off=zero,
        k=zero,
        q0=np.asarray(cfg["centre"]) + rng.uniform(-0.5, 0.5, n) * cfg["swing"],
        gc=zero,
        gs=zero,
        ca=zero,
        cb=zero,
        order=zero,
    )
    delay = 0
    if hidden == "delay":  # 1–3 ms at 1 kHz and faster, else one or two samples (drawn, not sized)
        delay = int(round(rng.choice([1, 2, 3]) * rate / 1000)) if rate >= 1000 else int(rng.choice([1, 2]))
    if hidden == "cogging":
        p["order"] = np.full(n, float(np.round(rng.uniform(25, 60))) if arm else 2 * np.pi / rng.uniform(0.005, 0.015))
    joint = None
    if hidden in ("stribeck", "asymmetry", "offset", "gravity", "spring", "cogging") and n > 1:
        joint = [None, 1, 2][int(rng.integers(3))]
    closed = excitation != "steps"
    quiet = np.zeros((steps, n))
    q, u = simulate(arm, p, ref, push, quiet, rate, delay, closed)
    disturbance = quiet
    info: dict = {}
    if torque == "coloured":
        level, corner = rng.uniform(0.03, 0.08), rng.uniform(1.0, 5.0)
        b, a = signal.butter(2, corner * 2 / rate)  # pyright: ignore[reportAssignmentType, reportGeneralTypeIssues] (the default output="ba")
        w = np.asarray(signal.lfilter(b, a, rng.standard_normal((steps, n)), axis=0))
        disturbance = w / w.std(0) * level * rms(u)
        info.update(disturbance_fraction=round(float(level), 3), disturbance_corner_hz=round(float(corner), 2))
    if hidden in ("stribeck", "asymmetry", "offset", "gravity", "spring", "cogging"):
        phase = float(rng.uniform(0, 2 * np.pi))
        sign = rng.choice([-1.0, 1.0], n) if hidden in ("offset", "gravity", "cogging") else np.ones(n)
        for _ in range(2):  # sized on the motion without it, then once more on the motion with it
            unit = _unit(hidden, cfg, p, q, np.gradient(q, 1.0 / rate, axis=0), phase)
            size = amplitude * rms(u) / np.maximum(rms(unit), 1e-12) * sign
            if joint is not None:
                size[2 - joint] = 0.0
            _set(hidden, p, size, phase)
            q, u = simulate(arm, p, ref, push, disturbance, rate, delay, closed)
    elif torque == "coloured" or delay:
        q, u = simulate(arm, p, ref, push, disturbance, rate, delay, closed)
    tau = u.copy()
    if torque == "white":
        level = rng.uniform(0.10, 0.30)
        tau = tau + rng.standard_normal(tau.shape) * level * rms(u)
        info["noise_fraction"] = round(float(level), 3)
    if delay:  # and what the late command changes, τ(t) − τ(t − d), against the torque (as the calibration)
        info["delay_ms"] = 1e3 * delay / rate
        info["hidden_fraction"] = [round(float(x), 4) for x in rms(u[delay:] - u[:-delay]) / np.maximum(rms(u), 1e-300)]
    rec = _round_trip(q, tau, rate, arm, hold == "stated")
    rec.path = f"<independent seed {seed}, hidden {hidden or 'nothing'}>"
    start = ",".join(e for e in NOMINAL if e != hidden)
    truth = {
        k: [float(x) for x in np.atleast_1d(v)]
        for k, v in p.items()
        if np.any(np.asarray(v) != 0) and (k != "q0" or hidden == "spring")
    }
    condition = {
        "seed": seed,
        "simulator": "independent",
        "structure": structure,
        "rate": rate,
        "excitation": excitation,
        "torque": torque,
        "hold": hold,
        **info,
    }
    return Case(rec, start, hidden, joint, condition, truth, time.perf_counter() - t_start)


def _round_trip(q: np.ndarray, tau: np.ndarray, rate: int, arm: bool, stated: bool):
    """Written as a CSV file and read back by manus's reader."""
    from manus.plants.recording import read

    n = q.shape[1]
    head = [f"# sample_rate_hz: {rate}"]
    head += (
        ["# counts_per_rev: 131072", "# structure: manus2"]
        if arm
        else [f"# position_step: {AXIS['step']:g}", "# structure: axis", "# joints: prismatic"]
    )
    if stated:
        head.append("# command_hold: zoh")
    head.append(",".join(["t"] + [f"q{i + 1}" for i in range(n)] + [f"tau{i + 1}" for i in range(n)]))
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "independent.csv")
        np.savetxt(
            path,
            np.column_stack([np.arange(len(q)) / rate, q, tau]),
            delimiter=",",
            fmt="%.10g",
            header="\n".join(head),
            comments="",
        )
        return read(path)
