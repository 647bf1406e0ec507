"""Instrumental variables for inverse-dynamics identification (IDIM-IV, after Janot, Gautier et
al.: "A generic instrumental variable approach for industrial robot identification", IEEE TCST
2014, the method of the EMPS authors).

Least squares on τ ≈ Y(q, q̇, q̈) θ is biased when the regressor is noisy: q̇ and q̈ come from
differentiated, quantized positions, and when the torque is a small difference of large terms
(a pendulum swung by a torque far smaller than gravity) the noise in q̈ pulls the inertia toward
zero (errors in variables). IV replaces Yᵀ in the normal equations by Zᵀ, with instruments Z
correlated with the true regressor but not with its noise: here Z = Y evaluated on the motion
*simulated* by the current model from the recorded command, which carries no measurement noise.
Iterated: simulate with θ_k, θ_{k+1} = (ZᵀY)⁻¹ Zᵀτ, at most `ITERATIONS` times, stopping once
no parameter moves by more than `CONVERGED` of its standard deviation (the instruments simulated
from θ_k gave θ_k back), or, under `auto`, once least squares is kept whatever the iterations
give (`settled`: IV within `SETTLED` combined standard deviations of LS on every parameter, and
LS breaking no rule; to be chosen, IV would have to move to `Z_DISAGREE`).

The simulation is the project's simulator (`manus.plants.Simulator`: exact stick-slip, the
model's delay, the command held over each period), run in windows of `WINDOW_S` restarted from
the measured (filtered) state with the commands recorded before each in the delay line, all
windows at once under `vmap`, so that an open-loop simulation's drift (or a closed loop that is
not modelled) does not decorrelate the instruments. A period is cut into sub-steps of at most
`SUBSTEP_S` (the scheme is second order: two at 1 kHz, one at 5 kHz), of `FINE_SUBSTEP_S` where
those diverge. The parameters are traced arrays: one compilation serves every iteration, and the
free run of an open-loop recording (`manus.experiments.freerun`), which simulates the same windows;
the last simulation is kept, so a free run of the parameters IV last simulated costs nothing.
"""

from __future__ import annotations

from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np

from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.prepare import Data
from manus.adaptive.identify.result import Fit, fit_rows
from manus.plants.devices import BATCH, split
from manus.plants.effects import Model
from manus.plants.simulator import Simulator
from manus.stored import stored_jit

ITERATIONS = 3  # at most
CONVERGED = 0.1  # the iterations stop once no parameter moves by more than this share of its std
WINDOW_S = 0.5  # simulated windows restart from the measured state this often
MIN_WINDOW = 8  # samples
SUBSTEP_S = 5e-4  # the simulation's sub-step [s] at most
FINE_SUBSTEP_S = 1e-4  # ... where that one diverges (a fast mode: a light joint under viscous friction)
Z_DISAGREE = 3.0  # LS and IV disagree when a parameter differs by more than this many std
SETTLED = 1.0  # under auto, IV within this many combined std of LS (which breaks no rule) keeps LS: no more iterations
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


def substeps(dt: float, step: float = SUBSTEP_S) -> int:
    """Sub-steps per control period: the fewest whose step is at most `step`."""
    return max(1, int(np.ceil(dt / step - 1e-9)))


def window_size(data: Data) -> int:
    """Samples per simulated window: `WINDOW_S`, at least `MIN_WINDOW`, at most the recording."""
    return int(max(MIN_WINDOW, min(round(WINDOW_S / data.dt), len(data.rec))))


_last: list = []  # the last simulation: [data, model, clipped parameters, its (q, q̇) or None]


@stored_jit
def _windows(sim: Simulator, q0, qd0, history, taus):
    """(q, q̇) of each window (its first axis), the windows split over the devices
    (`manus.plants.devices.split`)."""

    def one(sim, q0, qd0, history, tau):
        state, _ = sim.reset(None, q0, qd0)
        state = state._replace(commands=history)

        def tick(st, u):
            q, qd = sim.truth(st)
            st, _ = sim.step(st, u)
            return st, (q, qd)

        return jax.lax.scan(tick, state, tau)[1]

    each = jax.vmap(one, in_axes=(None, 0, 0, 0, 0))
    batch = jax.sharding.PartitionSpec(BATCH)
    return split(lambda sim, xs: each(sim, *xs), sim, (q0, qd0, history, taus), (batch, batch))


def windows(data: Data, model: Model, params: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """(q, q̇) of the model driven by the recorded command over the whole recording, in windows of
    `window_size` samples each restarted from the measured (filtered) state with the commands
    recorded before it in its delay line, `substeps` per period (of `FINE_SUBSTEP_S` where those
    diverge); None when it cannot be simulated (no inertia, an inertia not positive definite,
    divergence). Modal effects are left out; parameters below an effect's lower bound are
    clipped to it."""
    if not any(e.inertial for e in model.effects):
        return None  # without its inertia the model has no motion of its own to simulate
    sim_model = Model(model.structure, tuple(e for e in model.effects if not e.modal))
    p = _physical(sim_model, {k: params[k] for k in sim_model.names})
    if p is None:
        return None
    if _last and _last[0] is data and _last[1] is model and _last[2] == p:
        return _last[3]  # the free run of the parameters IV's last instruments came from
    dt, T, n, W = data.dt, len(data.rec), data.n_joints, window_size(data)
    count = int(np.ceil(T / W))
    count += -count % len(jax.devices())  # (windows after the end, dropped: one count per device)
    tau = np.asarray(data.rec.tau, float)
    starts = np.minimum(np.arange(count) * W, T - 1)
    taus = np.concatenate([tau, np.repeat(tau[-1:], count * W - T, 0)]).reshape(count, W, n)
    run = None
    for step in dict.fromkeys((substeps(dt), substeps(dt, FINE_SUBSTEP_S))):
        sim = Simulator(sim_model, p, rate_hz=1 / dt, substeps=step, actuator=None, encoder=None)
        lags = int(sim._lags().max()) + 1  # the delay line's length
        history = tau[np.clip(starts[:, None] - 1 - np.arange(lags)[None, :], 0, None)]
        q, qd = _windows(sim, *(jnp.asarray(x) for x in (data.q[starts], data.qd[starts], history, taus)))
        q, qd = np.asarray(q).reshape(-1, n)[:T], np.asarray(qd).reshape(-1, n)[:T]
        if np.all(np.isfinite(q)) and np.all(np.isfinite(qd)):
            run = (q, qd)
            break
    _last[:] = [data, model, p, run]
    return run


def simulate(data: Data, model: Model, params: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(q, q̇, q̈) of `windows`, q̈ differentiated inside each window; None as `windows`."""
    run = windows(data, model, params)
    if run is None:
        return None
    q, qd = run
    T, n, W = len(q), data.n_joints, window_size(data)
    per_window = np.pad(qd, ((0, -T % W), (0, 0))).reshape(-1, W, n)
    qdd = np.asarray(np.gradient(per_window, data.dt, axis=1)).reshape(-1, n)[:T]
    return q, qd, qdd


def instruments(data: Data, f: Fit) -> Columns | None:
    """The instruments' columns for the model of `f` at its parameters (None: no simulation)."""
    kin = simulate(data, f.model, f.params)
    return None if kin is None else Columns(data, kinematics=kin)


def iv_fit(data: Data, cols: Columns, ls: Fit, method: str, start: Fit | None = None) -> Fit:
    """IDIM-IV from the LS fit `ls` (at most ITERATIONS rounds, fewer once `converged`), the
    first instruments simulated from `start` (default `ls`; a serial chain's consistent
    parameters where `ls` breaks physics, `consistency.physical`); `method="auto"` keeps the one
    the evidence favours (`choose`) and says why."""
    current, iv = start or ls, None
    for _ in range(ITERATIONS):
        icols = instruments(data, current)
        if icols is None:
            break
        iv = fit_rows(data, cols, ls.model, ls.search, icols)
        if converged(current, iv) or (method == "auto" and settled(ls, iv)):
            break
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


def converged(before: Fit, after: Fit) -> bool:
    """Whether the instruments simulated from `before` gave back its parameters: each within
    `CONVERGED` of `after`'s standard deviation."""
    if before.names != after.names or before.model.spec != after.model.spec:
        return False
    sd = np.nan_to_num(after.std, nan=np.inf)
    return bool(np.all(np.abs(after.theta - before.theta) <= CONVERGED * sd))


def _z(ls: Fit, iv: Fit) -> np.ndarray:
    """Per parameter: |IV − LS| over their combined standard deviation (0 where that is 0)."""
    sd = np.sqrt(np.nan_to_num(ls.std, nan=np.inf) ** 2 + np.nan_to_num(iv.std, nan=np.inf) ** 2)
    return np.where(sd > 0, np.abs(iv.theta - ls.theta) / np.where(sd > 0, sd, 1), 0.0)


def settled(ls: Fit, iv: Fit) -> bool:
    """Whether `choose` keeps least squares whatever further iterations give: LS breaks no rule
    and IV lies within `SETTLED` combined standard deviations of it on every parameter (IV would
    have to move to `Z_DISAGREE` to be chosen)."""
    return not ls.violations() and bool(np.all(_z(ls, iv) < SETTLED))


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
    z = _z(ls, iv)
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
