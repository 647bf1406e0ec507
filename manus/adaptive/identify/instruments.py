"""Instrumental variables for inverse-dynamics identification (IDIM-IV, after Janot, Gautier et
al.: "A generic instrumental variable approach for industrial robot identification", IEEE TCST
2014, the method of the EMPS authors).

Least squares on τ ≈ Y(q, q̇, q̈) θ is biased when the regressor is noisy: q̇ and q̈ come from
differentiated, quantized positions, and when the torque is a small difference of large terms
(a pendulum swung by a torque far smaller than gravity) the noise in q̈ pulls the inertia toward
zero (errors in variables). IV replaces Yᵀ in the normal equations by Zᵀ, with instruments Z
correlated with the true regressor but not with its noise: here Z = Y evaluated on the motion
*simulated* by the current model from the recorded command, which carries no measurement noise.
Iterated: simulate with θ_k, θ_{k+1} = (ZᵀY)⁻¹ Zᵀτ.

The simulation is the project's simulator (`manus.plants.Simulator`: exact stick-slip, the
model's delay, the command held over each period), run in short windows restarted from the
measured (filtered) state, all windows at once under `vmap`, so that an open-loop simulation's
drift (or a closed loop that is not modelled) does not decorrelate the instruments.
"""

from __future__ import annotations

from dataclasses import replace

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.prepare import Data
from manus.adaptive.identify.result import Fit, fit_rows
from manus.plants.effects import Model
from manus.plants.simulator import Simulator

ITERATIONS = 3
WINDOW_S = 0.5  # simulated windows restart from the measured state this often
Z_DISAGREE = 3.0  # LS and IV disagree when a parameter differs by more than this many std
IV_WORSE = 1.5  # IV is not used when its error exceeds LS's by this factor (a model too wrong to simulate)


def _physical(model: Model, params: dict) -> dict | None:
    """The parameters clipped to each effect's lower bounds, or None when the rigid ones cannot
    be simulated (an inertia that is not positive definite)."""
    s = model.structure
    out = dict(params)
    for e in model.effects:
        for k, lo in zip(e.names(s), e.lower_bounds(s), strict=True):
            out[k] = max(out[k], lo)
    rigid = [e for e in model.effects if e.inertial]
    if rigid and rigid[0].violations(s, out):
        return None
    return out


@eqx.filter_jit
def _windows(sim: Simulator, q0, qd0, taus):
    def one(q0, qd0, tau):
        state, _ = sim.reset(None, q0, qd0)

        def tick(st, u):
            q, qd = sim.truth(st)
            st, _ = sim.step(st, u)
            return st, (q, qd)

        return jax.lax.scan(tick, state, tau)[1]

    return jax.vmap(one)(q0, qd0, taus)


def simulate(data: Data, model: Model, params: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(q, q̇, q̈) of the model driven by the recorded command, in windows restarted from the
    measured state; None when it cannot be simulated (unphysical inertia, divergence)."""
    if not any(e.inertial for e in model.effects):
        return None  # without its inertia the model has no motion of its own to simulate
    sim_model = Model(model.structure, tuple(e for e in model.effects if not e.modal))
    p = _physical(sim_model, {k: params[k] for k in sim_model.names})
    if p is None:
        return None
    dt, T, n = data.dt, len(data.rec), data.n_joints
    W = int(max(8, min(round(WINDOW_S / dt), T)))
    count = int(np.ceil(T / W))
    pad = count * W - T
    tau = np.concatenate([data.rec.tau, np.repeat(data.rec.tau[-1:], pad, 0)]).reshape(count, W, n)
    starts = np.minimum(np.arange(count) * W, T - 1)
    sim = Simulator(sim_model, p, rate_hz=1 / dt, substeps=10, actuator=None, encoder=None)
    q_sim, qd_sim = _windows(sim, jnp.asarray(data.q[starts]), jnp.asarray(data.qd[starts]), jnp.asarray(tau))
    q, qd = np.asarray(q_sim).reshape(-1, n)[:T], np.asarray(qd_sim).reshape(-1, n)[:T]
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
        return None
    per_window = qd.reshape(-1, W, n) if pad == 0 else np.pad(qd, ((0, pad), (0, 0))).reshape(-1, W, n)
    qdd = np.asarray(np.gradient(per_window, dt, axis=1)).reshape(-1, n)[:T]
    return q, qd, qdd


def instruments(data: Data, f: Fit) -> Columns | None:
    """The instruments' columns for the model of `f` at its parameters (None: no simulation)."""
    kin = simulate(data, f.model, f.params)
    return None if kin is None else Columns(data, kinematics=kin)


def iv_fit(data: Data, cols: Columns, ls: Fit, method: str, start: Fit | None = None) -> Fit:
    """IDIM-IV from the LS fit `ls` (ITERATIONS rounds), the first instruments simulated from
    `start` (default `ls`; a serial chain's consistent parameters where `ls` breaks physics,
    `consistency.physical`); `method="auto"` keeps the one the evidence favours (`choose`) and
    says why."""
    current, iv, icols = start or ls, None, None
    for _ in range(ITERATIONS):
        icols = instruments(data, current)
        if icols is None:
            break
        iv = fit_rows(data, cols, ls.model, ls.search, icols)
        current = iv
    if iv is None:
        why = (
            "it has no inertia to simulate"
            if not any(e.inertial for e in ls.model.effects)
            else "; ".join(ls.violations()) or "the simulation diverged"
        )
        return replace(
            ls,
            why=f"IV unavailable: the model cannot be simulated from the recorded command ({why}); least squares kept",
        )
    if method == "iv":
        return replace(iv, why="instrumental variables (asked for)")
    return choose(ls, iv)


def choose(ls: Fit, iv: Fit) -> Fit:
    """LS unless the evidence says it is biased: LS breaks physics where IV does not, or the
    two disagree beyond `Z_DISAGREE` combined standard deviations on some parameter; the one
    kept says why (`Fit.why`)."""
    bad_ls, bad_iv = ls.violations(), iv.violations()
    if not iv.rel_error < min(1.0, IV_WORSE * ls.rel_error):
        return replace(
            ls,
            why=f"IV explains the torque far worse than LS ({100 * iv.rel_error:.1f} % against "
            f"{100 * ls.rel_error:.1f} %): the model is too far from the data for its simulation to "
            "serve as instruments; least squares kept",
        )
    sd = np.sqrt(np.nan_to_num(ls.std, nan=np.inf) ** 2 + np.nan_to_num(iv.std, nan=np.inf) ** 2)
    z = np.where(sd > 0, np.abs(iv.theta - ls.theta) / np.where(sd > 0, sd, 1), 0.0)
    worst = int(np.argmax(z)) if z.size else 0
    if bad_ls and not bad_iv:
        return replace(iv, why=f"least squares breaks physics ({bad_ls[0]}); instrumental variables do not")
    if z.size and z[worst] > Z_DISAGREE and not bad_iv:
        return replace(
            iv,
            why=f"LS and IV disagree beyond their standard deviations ({ls.names[worst]}: LS "
            f"{ls.theta[worst]:.4g}, IV {iv.theta[worst]:.4g}, {z[worst]:.1f} std apart): noise in "
            "the differentiated regressor biases least squares",
        )
    agree = max(float(z.max(initial=0)), 0)
    why = (
        f"LS and IV agree within {agree:.1f} combined std: least squares, the more efficient"
        if not bad_iv
        else f"instrumental variables break physics ({bad_iv[0]}): least squares kept"
    )
    return replace(ls, why=why)
