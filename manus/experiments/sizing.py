"""How large a hidden effect is, on a recording's motion: its torque (from its regressor
columns), scaled to a share of the recorded torque's RMS; the part of it no other reading
explains (`distinct`); what a late command changes in the torque (`delay_change`), and the
shortest delay that changes it by a given share (`size_delay`).

A `setup` here is anything with a `structure`, its joint count `n` and whether it is
`prismatic` (`manus.experiments.calibration.Setup`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from manus.plants.effects import ORDER, VOCABULARY, Model

DELAY_MIN, DELAY_MAX = 1e-3, 0.05  # a hidden delay's range [s] (diagnose searches up to 2 % of the record, 100 ms)


def rms(x, axis=0):
    return np.sqrt(np.mean(np.asarray(x) ** 2, axis=axis))


def acceleration(qd: np.ndarray, dt: float) -> np.ndarray:
    """q̈ from the true velocity, by central differences."""
    return np.gradient(qd, dt, axis=0)


def applies(name: str, setup) -> bool:
    """Whether effect `name` can be hidden on this structure (gravity is a cos/sin of an angle:
    not on a prismatic axis)."""
    return VOCABULARY[name]().applies(setup.structure, (setup.prismatic,) * setup.n) is None


def effect_columns(setup, effect, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """A linear effect's regressor columns along a motion, (T, n, P)."""
    model = Model(setup.structure, (effect,))
    return np.asarray(jax.vmap(model.regressor)(jnp.asarray(q), jnp.asarray(qd), jnp.asarray(qdd)))


def effect_torque(setup, effect, params: dict, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """The torque (T, n) a linear effect adds along a motion."""
    theta = np.array([params.get(k, 0.0) for k in effect.names(setup.structure)], float)
    return effect_columns(setup, effect, q, qd, qdd) @ theta


def parameter_joints(setup, effect) -> dict[str, int | None]:
    """For each linear parameter of `effect`: the 0-based joint its column acts on, or None when
    it acts on several (the arm's a2) — from the regressor itself, not from the names."""
    rng = np.random.default_rng(0)
    scales = np.repeat(10.0 ** np.arange(-4, 1), 8)[:, None]  # speeds from 1e-4 to 1 (Stribeck's exp(−(q̇/vs)²))
    Y = effect_columns(setup, effect, *(rng.normal(size=(scales.size, setup.n)) * scales for _ in range(3)))
    out = {}
    for p, name in enumerate(effect.names(setup.structure)):
        on = np.flatnonzero(np.abs(Y[:, :, p]).max(axis=0) > 0)
        out[name] = int(on[0]) if on.size == 1 else None
    return out


def scale_hidden(
    setup, effect, unit: dict, joint: int | None, traj, fraction: float, dt: float
) -> tuple[dict, np.ndarray]:
    """The hidden effect's parameters: `unit` scaled, per joint (or as a whole when its parameters
    are shared between joints), so that its torque along `traj` is `fraction` of the recorded
    torque's RMS. Returns (params, the fraction each joint would get before the scaling)."""
    owner = parameter_joints(setup, effect)
    tau_e = effect_torque(setup, effect, unit, traj.q_true, traj.qd_true, acceleration(traj.qd_true, dt))
    tau = np.asarray(traj.tau)
    ratio = rms(tau_e) / np.maximum(rms(tau), 1e-300)
    out = {}
    if any(j is None for j in owner.values()):  # shared parameters: one factor for the effect
        whole = rms(tau_e.ravel()) / max(rms(tau.ravel()), 1e-300)
        f = fraction / whole if whole > 0 else 0.0
        out = {k: v * f for k, v in unit.items()}
    else:
        for k, v in unit.items():
            j = owner[k]
            if joint is not None and j != joint - 1:
                out[k] = 0.0
            else:
                out[k] = v * fraction / ratio[j] if ratio[j] > 0 else 0.0
    return out, ratio


def achieved(setup, effect, params: dict, traj, dt: float, joint: int | None) -> list[float]:
    """The hidden effect's torque RMS along `traj` as a fraction of the recorded torque's, per joint."""
    tau_e = effect_torque(setup, effect, params, traj.q_true, traj.qd_true, acceleration(traj.qd_true, dt))
    return [float(x) for x in rms(tau_e) / np.maximum(rms(np.asarray(traj.tau)), 1e-300)]


def distinct(setup, effect, params: dict, start: str, traj, dt: float, others: tuple = ()) -> float:
    """How much of the hidden effect no other reading explains: the RMS of its torque along the
    true motion once projected off the span of the start model plus any one other linear
    effect of the vocabulary that diagnose would offer on top of it (with the effects it brings;
    `others` gives the non-linear parameters the truth uses: the cogging order, the Stribeck
    velocity), the smallest over those, as a fraction of the recorded torque's RMS (all joints).
    A hidden gravity on a small swing is mostly a constant: its distinct part is what sets it
    apart from an offset, and no procedure can name it from less."""
    q, qd = np.asarray(traj.q_true), np.asarray(traj.qd_true)
    motion = (q, qd, acceleration(qd, dt))
    tau_h = effect_torque(setup, effect, params, *motion).ravel()
    scale = max(rms(np.asarray(traj.tau).ravel()), 1e-300)
    by_name = {e.name: e for e in others}
    of = lambda name: by_name.get(name) or VOCABULARY[name]()
    cols: dict = {}

    def columns(name):  # one effect's columns along the motion, (T·n, p), computed once
        if name not in cols:
            Y = effect_columns(setup, of(name), *motion)
            cols[name] = Y.reshape(-1, Y.shape[-1])
        return cols[name]

    base = start.split(",") if start else []
    worst = rms(tau_h) / scale
    for name in ORDER:
        rival = of(name)
        if (
            name == effect.name
            or name in base
            or not rival.linear
            or not applies(name, setup)
            or any(r not in base for r in rival.requires)
        ):  # (diagnose would not offer it)
            continue
        with_ = [b for b in rival.brings if b != effect.name and b not in base] + [name]
        Y = np.concatenate([columns(b) for b in base + with_], axis=1)
        coef = np.linalg.lstsq(Y, tau_h, rcond=None)[0]
        worst = min(worst, rms(tau_h - Y @ coef) / scale)
    return float(worst)


def delay_change(tau: np.ndarray, seconds: float, rate: float) -> np.ndarray:
    """What a command `seconds` late changes in the torque: the RMS of τ(t) − τ(t − d) (linear
    interpolation between samples), per joint and then for all joints together (last entry), as
    a fraction of the torque's RMS."""
    tau = np.asarray(tau, float)
    t = np.arange(len(tau), dtype=float)
    lag = seconds * rate
    k = min(int(np.ceil(lag)), len(tau) - 1)
    late = np.stack([np.interp(t - lag, t, tau[:, j]) for j in range(tau.shape[1])], axis=1)
    diff, ref = (tau - late)[k:], tau[k:]
    scale = np.r_[np.maximum(rms(ref), 1e-300), max(rms(ref.ravel()), 1e-300)]
    return np.r_[rms(diff), rms(diff.ravel())] / scale


def size_delay(tau: np.ndarray, rate: float, amplitude: float) -> float:
    """The shortest delay [s], on a 0.1 ms grid from 1 ms to `DELAY_MAX`, whose change of the
    torque `tau` (all joints together) reaches `amplitude` of its RMS; `DELAY_MAX` if none does."""
    for d in np.arange(DELAY_MIN, DELAY_MAX + 1e-12, 1e-4):
        if delay_change(tau, d, rate)[-1] >= amplitude:
            return round(float(d), 4)
    return DELAY_MAX
