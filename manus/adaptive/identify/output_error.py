"""Output-error identification (OE): the parameters whose simulation, driven by the recorded
command, follows the recorded positions.

Inverse-dynamics least squares fits the torque to a regressor built from differentiated
positions. Where the encoder is coarse, the rate low or the motion chatters, the quantization
noise in q̈ at the cut-off can be as large as what identifies the inertia: least squares is then
pulled toward zero (errors in variables), and where the torque is a small difference of large
terms (a pendulum swung by a torque far below its gravity) the inertia and the gravity load
collapse together; IV's instruments, simulated from that estimate, are too far from the data
to help. OE compares positions only, the encoder's own output, with nothing differentiated.

Multiple shooting: the recording is cut into windows (`window_samples`: a quarter of the
motion's own period, RMS(q̇)/RMS(q̈) from the prepared kinematics, between `MIN_WINDOW` samples
and `MAX_WINDOW_S`: long enough for the inertia to show in the positions, short enough that an
unstable or drifting model stays near the data). Each window is simulated by the project's
simulator (`manus.plants.Simulator`: the model's own equations, its exact stick-slip, its delay,
the command held over each period) from the measured position at its start (the kinematic
band's q) with an initial velocity of its own: a free parameter per window and joint, started
at the measured q̇ (a q̇ differentiated from a coarse encoder is what OE avoids). The cost is
Σ ‖q_sim − q‖² over every window's samples, q the positions as recorded.

It is minimised by Levenberg–Marquardt on the linear parameters, the windows' velocities fitted
again at each trial (variable projection: the cost of θ is the least over the velocities) and
eliminated from each step by their Schur complement (each acts on its own window only). The
start is the estimate whose simulation follows the positions best among what LS and IV gave, LS,
and where the noise is notable the errors-in-variables family (`Quantization.family`): least
squares collapsed a thousandfold is still a start. Derivatives are forward differences of the
compiled simulation, all windows at once (`Problem`). Parameters stay within their effects'
lower bounds (b, Fc ≥ 0), and a step that leaves the inertia not positive definite is refused.
Dry friction is the simulator's exact stick-slip, no smooth surrogate: a stuck step does not move
with the parameters, a sliding one with its friction level, and the cost is piecewise smooth
(where a window sticks or not depends on the parameters, it may hold local minima: the start
matters).

Standard deviations: the Gauss–Newton Hessian (the windows' velocities profiled out) with the
scores summed per window (a sandwich: the error is correlated from sample to sample inside a
window, windows restart from the measured state).

`oe_reason` says when `auto` needs OE before IV: where the quantization noise in q̈ at the
cut-off makes up `NOISE_SHARE` or more of what identifies an inertial parameter (LS is pulled
toward zero by about that share); `rescue`, after IV kept least squares although it breaks
physics, where that noise is a notable share (`FAMILY_SHARE`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import jax
import jax.numpy as jnp
import numpy as np

from manus.adaptive.identify.columns import Columns
from manus.adaptive.identify.prepare import Data
from manus.adaptive.identify.result import Fit
from manus.estimators.offline import differentiate, edge, lowpass
from manus.plants.effects import Model
from manus.plants.errors import ModelError
from manus.plants.simulator import Simulator
from manus.stored import stored_jit

MIN_WINDOW = 20  # samples: fewer carry too little of the inertia's effect on the positions
MAX_WINDOW_S = 0.5  # longer windows let an unstable model (a pendulum balanced upright) leave the data
SUBSTEP_S = 5e-4  # the simulation's sub-step [s] at most
MAX_ITERATIONS = 40
TOLERANCE = 1e-6  # relative fall of the cost below which the iterations stop
VELOCITY_TOLERANCE = 1e-4  # ... and the fitting of the windows' velocities at one θ
DIFFERENCE = 1e-6  # a forward difference's step, relative to the parameter's scale
NOISE_SHARE = 0.25  # `auto` chooses OE where q̈'s quantization noise is this share of an inertial column
FAMILY_SHARE = 0.05  # OE's start is searched along the errors-in-variables family above this share


@dataclass
class OutputErrorFit(Fit):
    """A `Fit` by output error, with its position errors (`report()["output_error"]`)."""

    position_rms: list[float] = field(default_factory=list)  # per joint: RMS of q_sim − q [rad or m]
    position_rel: float = np.nan  # ‖q_sim − q‖ / ‖q − q(window start)‖ over every window
    start: str = ""  # the estimate OE started from (`_starts`)
    compared: str = ""  # the method LS and IV would have given ("ls" or "iv") ...
    compared_position_rel: float = np.nan  # ... and its position error (its own best window velocities)
    window_s: float = np.nan
    windows: int = 0
    iterations: int = 0
    evaluations: int = 0  # simulations (with their derivatives) of every window

    def report(self) -> dict:
        out = super().report()
        out["output_error"] = {
            "position_rms": self.position_rms,
            "position_rel_error": self.position_rel,
            "encoder_step": float(self.data.step),
            "compared": {
                "method": self.compared,
                "position_rel_error": self.compared_position_rel if np.isfinite(self.compared_position_rel) else None,
            },
            "start": self.start,
            "window_s": self.window_s,
            "windows": self.windows,
            "iterations": self.iterations,
            "simulations": self.evaluations,
        }
        return out


# -- when least squares cannot carry the fit ------------------------------------------------------


@dataclass(frozen=True)
class Quantization:
    """A model's least-squares normal equations on the data, G = XᵀX and h = Xᵀτ over its
    identifiable columns `names` (scaled to unit RMS), and NN: what the encoder's quantization
    noise adds to G in expectation (errors in variables: LS ≈ (I − G⁻¹NN) θ). The noise is a white
    quantization error (step Δ, variance Δ²/12) through the same differentiator and low-pass as
    the data (`_qdd_noise_variance`), carried by the inertial columns through q̈ (H_k(q) e_j on the
    used rows); its share in the velocity- and position-driven columns is left out (the q̈ noise
    is larger by the band's square)."""

    names: list[str]
    inertial: list[str]
    G: np.ndarray
    h: np.ndarray
    NN: np.ndarray
    scale: np.ndarray

    def share(self) -> dict[str, float]:
        """Per inertial parameter: the share of what identifies it (its column's variance the
        other columns do not explain, 1/[G⁻¹]ₖₖ) that is noise, (NN)ₖₖ [G⁻¹]ₖₖ: least squares
        is pulled toward zero by about that share."""
        G_inv = np.linalg.pinv(self.G, rcond=1e-12)
        return {k: float(self.NN[i, i] * G_inv[i, i]) for i, k in enumerate(self.names) if k in self.inertial}

    def family(self, count: int = 10) -> list[dict[str, float]]:
        """The bias-compensated estimates θ(κ) = (G − κ NN)⁻¹ h for κ from 0 (least squares)
        toward the κ where G − κ NN becomes singular (κ = κ_max (1 − 2⁻ⁱ)): the noise's pull
        undone by every amount up to a thousandfold collapse."""
        G_inv = np.linalg.pinv(self.G, rcond=1e-12)
        top = float(np.max(np.real(np.linalg.eigvals(G_inv @ self.NN))))
        if not top > 0:
            return []
        out = []
        for i in range(count + 1):
            kappa = (1 - 2.0**-i) / top
            theta = np.linalg.lstsq(self.G - kappa * self.NN, self.h, rcond=1e-12)[0] / self.scale
            out.append(dict(zip(self.names, theta.tolist(), strict=True)))
        return out


def quantization(data: Data, cols: Columns, f: Fit) -> Quantization | None:
    """The errors-in-variables statistics of `f`'s model on `data`; None without a known encoder
    step or an inertial effect, or where a first estimate puts the noise's share of every
    inertial column under a tenth of `FAMILY_SHARE` (the share read as the noise-to-signal ratio
    of q̈ on the used rows times the column's variance inflation ‖X_k‖²[G⁻¹]ₖₖ: the columns'
    response to q̈ is then never evaluated, nor compiled)."""
    model = f.model
    rigid = [e for e in model.effects if e.inertial]
    if not rigid or not data.step > 0 or data.rows.size == 0:
        return None
    sub = Model(model.structure, tuple(rigid))
    names = [k for k in model.names if k not in f.redundant]
    inertial = [k for k in sub.names if k in names]
    every = list(model.names)  # (a chain's names are worked out on each call)
    idx = [every.index(k) for k in names]
    X = cols.model(model)[:, :, idx].reshape(-1, len(idx))
    scale = np.sqrt(np.mean(X**2, axis=0)) + 1e-300
    X = X / scale
    G = X.T @ X
    at = [names.index(k) for k in inertial]
    sigma2 = _qdd_noise_variance(data)
    signal = np.mean(data.smoothed(data.work(data.qdd), data.rows) ** 2, axis=0)
    inflation = np.diag(G)[at] * np.diag(np.linalg.pinv(G, rcond=1e-12))[at]
    if not np.max(sigma2 / np.maximum(signal, 1e-300)) * np.max(inflation, initial=0) >= FAMILY_SHARE / 10:
        return None
    Hk = np.asarray(_unit_responses(sub, jnp.asarray(data.q[data.rows])))  # (joint, rows, n, p)
    if data.mask is not None:
        Hk = Hk * data.mask[None, :, :, None]
    within = [list(sub.names).index(k) for k in inertial]
    Hs = Hk[..., within] / scale[at]
    NN = np.zeros((len(names), len(names)))
    NN[np.ix_(at, at)] = sigma2 * np.einsum("jrip,jriq->pq", Hs, Hs)
    tau = data.tau(f.delay).reshape(-1)
    return Quantization(names, inertial, G, X.T @ tau, NN, scale)


@stored_jit
def _unit_responses(model: Model, q):
    """(joint j, rows, n, p): the model's columns' response to a unit q̈ on joint j at rest at q."""
    zero = jnp.zeros_like(q)
    reg = jax.vmap(model.regressor)
    base = reg(q, zero, zero)
    return jnp.stack([reg(q, zero, zero.at[:, j].set(1.0)) - base for j in range(q.shape[1])])


def _qdd_noise_variance(data: Data) -> float:
    """Variance of the quantization noise in q̈ as the columns carry it: a white error uniform
    over one encoder step, differentiated at the kinematic band, low-passed at the cut-off."""
    e = (np.random.default_rng(0).random(len(data.rec)) - 0.5) * data.step
    qdd = lowpass(differentiate(e, data.dt, data.kinematic_hz)[2], data.dt, data.cutoff_hz)
    cut = edge(data.dt, data.cutoff_hz)
    inner = qdd[cut : len(qdd) - cut] if len(qdd) > 2 * cut + 1 else qdd
    return float(np.mean(inner**2))


def oe_reason(data: Data, ls: Fit, noise: Quantization | None) -> str:
    """Why `auto` needs output error before IV is tried ("" when it does not): the quantization
    noise makes up `NOISE_SHARE` or more of what identifies an inertial parameter (IV's
    instruments, simulated from that collapsed estimate, would be too far from the data)."""
    share = noise.share() if noise is not None else {}
    if not share:
        return ""
    k = max(share, key=lambda name: share[name])
    if share[k] < NOISE_SHARE:
        return ""
    return (
        f"the encoder's quantization noise in q̈ at the {data.cutoff_hz:.3g} Hz cut-off is {100 * share[k]:.0f} % "
        f"of what identifies {k} (step {data.step:.3g}): least squares is pulled toward zero (LS {k} = "
        f"{ls.params[k]:.4g}); output error fits the positions, nothing differentiated"
    )


def rescue(data: Data, cols: Columns, ls: Fit, kept: Fit, noise: Quantization | None) -> Fit:
    """`auto` after IV kept least squares (`kept`): where those parameters break physics and the
    quantization noise is a notable share of an inertial column (`FAMILY_SHARE`), the OE fit
    (IV was refused or broke physics too); else `kept`."""
    share = noise.share() if noise is not None else {}
    bad = kept.violations() if kept.unconstrained is None else []  # (a chain's consistent stage: nothing broken)
    if not (bad and share and max(share.values()) >= FAMILY_SHARE):
        return kept
    k = max(share, key=lambda name: share[name])
    why = (
        f"least squares breaks physics ({bad[0]}) and IV does not rescue it ({kept.why}); the encoder's "
        f"quantization noise in q̈ is {100 * share[k]:.0f} % of what identifies {k}: output error fits the positions"
    )
    try:
        return output_error(data, cols, ls, why, kept, noise)
    except ModelError as e:
        return replace(kept, why=f"{kept.why}; output error was tried ({e})")


# -- the simulation over windows -------------------------------------------------------------------


def window_samples(data: Data) -> int:
    """Samples per window: a quarter of the motion's period, (π/2)·RMS(q̇)/RMS(q̈) on the used
    rows (the joint whose motion is quickest), within `MIN_WINDOW` samples and `MAX_WINDOW_S`."""
    rows = data.rows if data.rows.size else np.arange(len(data.rec))
    qd = np.sqrt(np.mean(data.qd[rows] ** 2, axis=0))
    qdd = np.sqrt(np.mean(data.smoothed(data.work(data.qdd), rows) ** 2, axis=0))
    moving = qdd > 0
    period = float(np.min(qd[moving] / qdd[moving])) * np.pi / 2 if moving.any() else MAX_WINDOW_S
    T = int(round(min(period, MAX_WINDOW_S) / data.dt))
    return int(np.clip(T, MIN_WINDOW, max(MIN_WINDOW, (len(data.rec) - 2) // 2)))


@dataclass(frozen=True)
class Windows:
    """The windows a recording is cut into: each one's start sample, measured state, command
    history (newest first, for a delayed command) and commands, and the recorded positions."""

    starts: np.ndarray  # (K,)
    q0: np.ndarray  # (K, n)
    qd0: np.ndarray  # (K, n)
    history: np.ndarray  # (K, L, n)
    tau: np.ndarray  # (K, W, n)
    q: np.ndarray  # (K, W, n): recorded positions at the W samples after each start
    size: int  # W

    @classmethod
    def of(cls, data: Data, size: int, lags: int) -> Windows:
        T, cut = len(data.rec), min(edge(data.dt, data.cutoff_hz), len(data.rec) // 4)
        starts = np.arange(cut, T - cut - size, size)
        if starts.size == 0:
            raise ModelError(
                f"{data.rec.path}: too short for output error: no window of {size} samples "
                f"({size * data.dt:.3g} s) fits between the filter's edges"
            )
        tau, q = np.asarray(data.rec.tau, float), np.asarray(data.rec.q, float)
        span = starts[:, None] + np.arange(size)[None, :]
        back = np.clip(starts[:, None] - 1 - np.arange(lags)[None, :], 0, None)
        return cls(starts, data.q[starts], data.qd[starts], tau[back], tau[span], q[span + 1], size)

    def arrays(self) -> tuple:
        """(q0, history, commands, positions) as JAX arrays, in the order the simulation takes them."""
        return tuple(jnp.asarray(x) for x in (self.q0, self.history, self.tau, self.q))


def _simulate(model: Model, rate: float, substeps: int, params: dict, q0, qd0, history, tau):
    """Positions (W, n) after each of the window's commands, from (q0, q̇0)."""
    sim = Simulator(model, params, rate_hz=rate, substeps=substeps, actuator=None, encoder=None)
    state, _ = sim.reset(None, q0, qd0)
    state = state._replace(commands=history)

    def tick(st, u):
        st, _ = sim.step(st, u)
        return st, st.q

    return jax.lax.scan(tick, state, tau)[1]


def _params(names: tuple, free: tuple, theta, fixed) -> dict:
    """Every parameter by name: the free ones from θ, the others from `fixed` (in `names` order)."""
    return {k: theta[free.index(k)] if k in free else fixed[j] for j, k in enumerate(names)}


@stored_jit
def _residuals(model, rate, substeps, free, fixed, theta, qd0, arrays):
    """q_sim − q of every window (K, W, n) (`arrays`: `Windows.arrays`)."""

    def one(qd0, q0, history, tau, q):
        return _simulate(model, rate, substeps, _params(model.names, free, theta, fixed), q0, qd0, history, tau) - q

    return jax.vmap(one)(qd0, *arrays)


class Problem:
    """One model's output-error problem on one prepared recording: the windows, the simulator's
    settings and which parameters are free (the others held: redundant ones at 0). Derivatives
    are forward differences of the compiled simulation (`DIFFERENCE` of each parameter's scale;
    one simulation per free parameter, and one per joint for every window's velocity at once):
    forward-mode differentiation through the simulator gives the same numbers but compiles
    2.5–3 times as long (14 s against 5.5 s for MANUS-2's windows), more than the whole fit."""

    def __init__(self, data: Data, model: Model, start: dict[str, float], held: set[str], scale: dict[str, float]):
        self.data = data
        self.model = Model(model.structure, tuple(e for e in model.effects if not e.modal))
        self.rate = 1.0 / data.dt
        self.substeps = max(1, int(np.ceil(data.dt / SUBSTEP_S)))
        probe = Simulator(self.model, None, rate_hz=self.rate, substeps=self.substeps, actuator=None, encoder=None)
        lags = int(probe._lags().max()) + 1
        self.size = window_samples(data)
        self.w = Windows.of(data, self.size, lags)
        names = list(self.model.names)
        self.free = tuple(k for k in names if k not in held)
        self.fixed = {k: float(start[k]) for k in names if k not in self.free}
        fixed = jnp.asarray([self.fixed.get(k, 0.0) for k in names], float)
        s = self.model.structure
        self.lower = np.array(
            [
                lo
                for e in self.model.effects
                for k, lo in zip(e.names(s), e.lower_bounds(s), strict=True)
                if k in self.free
            ]
        )
        self.steps = DIFFERENCE * np.array([max(abs(scale.get(k, 0.0)), 1e-12) for k in self.free])
        speed = np.sqrt(np.mean(data.qd**2, axis=0))
        self.v_steps = DIFFERENCE * np.maximum(speed, 1e-12)
        self.rigid = [e for e in self.model.effects if e.inertial]
        self.args = (self.model, self.rate, self.substeps, self.free, fixed)
        self.arrays = self.w.arrays()
        self.evaluations = 0

    def vector(self, params: dict[str, float]) -> np.ndarray:
        return np.array([params[k] for k in self.free], float)

    def simulable(self, theta: np.ndarray) -> bool:
        p = {**self.fixed, **dict(zip(self.free, theta.tolist(), strict=True))}
        return bool(self.rigid) and not self.rigid[0].violations(self.model.structure, p)

    def residuals(self, theta: np.ndarray, qd0: np.ndarray) -> np.ndarray:
        """(K, W·n): q_sim − q of every window, at θ and the windows' velocities."""
        self.evaluations += 1
        r = _residuals(*self.args, jnp.asarray(theta, float), jnp.asarray(qd0, float), self.arrays)
        return np.asarray(r).reshape(len(qd0), -1)

    def by_velocity(self, theta: np.ndarray, qd0: np.ndarray, r: np.ndarray) -> np.ndarray:
        """(K, W·n, n): ∂r/∂(each window's own initial velocity), every window at once per joint."""
        cols = []
        for j, h in enumerate(self.v_steps):
            moved = qd0.copy()
            moved[:, j] += h
            cols.append((self.residuals(theta, moved) - r) / h)
        return np.stack(cols, axis=-1)

    def by_theta(self, theta: np.ndarray, qd0: np.ndarray, r: np.ndarray) -> np.ndarray:
        """(K, W·n, P): ∂r/∂θ."""
        cols = []
        for i, h in enumerate(self.steps):
            moved = theta.copy()
            moved[i] += h if moved[i] + h >= self.lower[i] or not np.isfinite(self.lower[i]) else -h
            cols.append((self.residuals(moved, qd0) - r) / (moved[i] - theta[i]))
        return np.stack(cols, axis=-1)


def _window_costs(r: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore", invalid="ignore"):  # (a diverged window's cost is inf)
        c = np.sum(r**2, axis=1)
    return np.where(np.isfinite(c), c, np.inf)


def _finite(J: np.ndarray) -> np.ndarray:
    """A Jacobian with a diverged window's entries (not finite) at 0: that window takes no step."""
    return np.nan_to_num(J, nan=0.0, posinf=0.0, neginf=0.0)


def _velocities(problem: Problem, theta: np.ndarray, qd0: np.ndarray, rounds: int = 5):
    """Each window's initial velocity that best fits its positions at θ, from `qd0` (Gauss–Newton
    per window, a window's step shortened while it does not lower that window's cost); returns
    (velocities, r, J_v) there."""
    r = problem.residuals(theta, qd0)
    cost = _window_costs(r)
    n = len(problem.v_steps)
    shrink = np.ones(len(qd0))
    Jv = _finite(problem.by_velocity(theta, qd0, r))
    for _ in range(rounds):
        D = np.einsum("kip,kiq->kpq", Jv, Jv) + 1e-300 * np.eye(n)
        step = -np.einsum("kpq,kq->kp", np.linalg.pinv(D), np.einsum("kip,ki->kp", Jv, np.nan_to_num(r)))
        trial = qd0 + shrink[:, None] * step
        r2 = problem.residuals(theta, trial)
        c2 = _window_costs(r2)
        better = c2 < cost
        fall = float(np.sum(np.where(better, cost - c2, 0.0)) / max(float(np.sum(cost)), 1e-300))
        qd0 = np.where(better[:, None], trial, qd0)
        r = np.where(better[:, None], r2, r)
        cost = np.where(better, c2, cost)
        shrink = np.where(better, 1.0, shrink / 4)
        if better.any():
            Jv = _finite(problem.by_velocity(theta, qd0, r))
        if fall < VELOCITY_TOLERANCE:
            break
    return qd0, r, Jv


def _reduced(r, Jt, Jv):
    """The Gauss–Newton system of θ with the windows' velocities profiled out: (S, g, per-window
    scores, B, D⁻¹, J_vᵀr), S = Σ J_θᵀJ_θ − B D⁻¹ Bᵀ, B = J_θᵀJ_v, D = J_vᵀJ_v per window."""
    n = Jv.shape[-1]
    Dinv = np.linalg.pinv(np.einsum("kip,kiq->kpq", Jv, Jv) + 1e-300 * np.eye(n))
    B = np.einsum("kip,kiq->kpq", Jt, Jv)
    S = np.einsum("kip,kiq->pq", Jt, Jt) - np.einsum("kpa,kab,kqb->pq", B, Dinv, B)
    gv = np.einsum("kip,ki->kp", Jv, r)
    score = np.einsum("kip,ki->kp", Jt, r) - np.einsum("kpa,kab,kb->kp", B, Dinv, gv)
    return S, score.sum(0), score, B, Dinv, gv


def _minimise(problem: Problem, theta: np.ndarray, qd0: np.ndarray):
    """Levenberg–Marquardt on θ, each trial's window velocities fitted again from their linear
    prediction (variable projection: the cost of θ is the least over the velocities); `qd0` the
    best velocities at θ. Returns (θ, velocities, r, J_θ, J_v, iterations)."""
    qd0, r, Jv = _velocities(problem, theta, qd0, rounds=6)
    Jt = problem.by_theta(theta, qd0, r)
    cost = float(np.sum(_window_costs(r)))
    lam, done = 1e-3, 0
    while done < MAX_ITERATIONS:
        S, g, _, B, Dinv, gv = _reduced(r, Jt, Jv)
        accepted = False
        for _ in range(10):
            dt = -np.linalg.lstsq(S + lam * np.diag(np.diag(S)), g, rcond=1e-12)[0]
            th_new = np.maximum(theta + dt, problem.lower)
            if problem.simulable(th_new):
                dv = -np.einsum("kpq,kq->kp", Dinv, gv + np.einsum("kpq,p->kq", B, th_new - theta))
                v_new, r_new, Jv_new = _velocities(problem, th_new, qd0 + dv, rounds=6)
                new_cost = float(np.sum(_window_costs(r_new)))
                if new_cost < cost:
                    accepted = True
                    break
            lam *= 5
        if not accepted:
            break
        fall = (cost - new_cost) / max(cost, 1e-300)
        theta, qd0, r, Jv, cost = th_new, v_new, r_new, Jv_new, new_cost
        Jt = problem.by_theta(theta, qd0, r)
        done += 1
        lam = max(lam / 5, 1e-9)
        if fall < TOLERANCE:
            break
    return theta, qd0, r, Jt, Jv, done


def _std(r, Jt, Jv) -> np.ndarray:
    """θ's standard deviations: the Gauss–Newton Hessian (velocities profiled out) sandwiched
    with the scores summed per window."""
    S, _, score, *_ = _reduced(r, Jt, Jv)
    K = len(score)
    meat = score.T @ score * K / max(K - 1, 1)
    S_inv = np.linalg.pinv(S, rcond=1e-12)
    return np.sqrt(np.maximum(np.diag(S_inv @ meat @ S_inv), 0))


def _rel(r: np.ndarray, w: Windows) -> float:
    motion = w.q - w.q0[:, None, :]
    denom = np.linalg.norm(motion)
    return float(np.linalg.norm(r) / denom) if denom > 0 else np.inf


def _starts(ls: Fit, other: Fit | None, noise: Quantization | None) -> list[tuple[str, dict[str, float]]]:
    """The estimates OE may start from: `other` (what LS and IV gave: LS, IV, a chain's consistent
    set), LS, and where the quantization noise is a notable share of an inertial column
    (`FAMILY_SHARE`), the errors-in-variables family (`Quantization.family`)."""
    out = [(other.method, other.params)] if other is not None and other is not ls else []
    out.append(("ls", ls.params))
    share = noise.share() if noise is not None else {}
    if noise is not None and share and max(share.values()) >= FAMILY_SHARE:
        family = noise.family()
        for i, p in enumerate(family[1:], start=1):
            out.append((f"ls compensated for 1 − 2^-{i} of the largest noise it can hold", {**ls.params, **p}))
    return out


def output_error(
    data: Data, cols: Columns, ls: Fit, why: str, other: Fit | None = None, noise: Quantization | None = None
) -> OutputErrorFit:
    """The OE fit of `ls.model` on `data`, started from the estimate (`_starts`) whose simulation
    follows the positions best; `why` is the report's `method_why`. Refused (ModelError) where
    the model has no inertia, no start can be simulated, or its simulation leaves the recorded
    motion so far that the minimisation's steps are not finite."""
    model = ls.model
    if not any(e.inertial for e in model.effects):
        raise ModelError(f"output error simulates the model: {model.spec} has no inertia (add rigid)")
    scale = {k: max(abs(v), np.nan_to_num(s)) for (k, v), s in zip(ls.params.items(), ls.std, strict=True)}
    problem = Problem(data, model, ls.params, set(ls.redundant), scale)
    w = problem.w
    measured = np.asarray(w.qd0, float)
    best, compared = None, np.nan
    for i, (label, params) in enumerate(_starts(ls, other, noise)):
        theta = np.maximum(problem.vector(params), problem.lower)
        if not problem.simulable(theta):
            continue
        qd0, r, _ = _velocities(problem, theta, measured, rounds=6)
        cost = float(np.sum(_window_costs(r)))
        if i == 0:  # what LS and IV gave
            compared = _rel(r.reshape(w.q.shape), w)
        if best is None or cost < best[0]:
            best = (cost, label, theta, qd0)
    if best is None:
        bad = "; ".join(ls.violations()) or "its inertia is not positive definite"
        raise ModelError(f"output error: no estimate to start from can be simulated (LS: {bad})")
    _, label, theta0, qd0 = best
    try:
        theta, _, r, Jt, Jv, its = _minimise(problem, theta0, qd0)
        std_free = _std(r, Jt, Jv)
    except np.linalg.LinAlgError as e:  # (a window's simulation left the data: its steps are not finite)
        raise ModelError(
            f"output error: the simulation of {model.spec} from the recorded command leaves the recorded "
            f"motion within a window ({e}): the model lacks what holds the motion (gravity, a spring?) "
            "or cannot follow it; fit it with --method ls, or add the missing effect"
        ) from None
    names = list(ls.names)
    values = {**problem.fixed, **dict(zip(problem.free, theta.tolist(), strict=True))}
    full = np.array([values[k] for k in names])
    std = np.full(len(names), np.nan)
    for k, s in zip(problem.free, std_free, strict=True):
        std[names.index(k)] = s
    res = r.reshape(w.q.shape)
    tau = data.tau(ls.delay)
    resid = tau - cols.model(model) @ full
    denom = np.linalg.norm(tau)
    return OutputErrorFit(
        model,
        names,
        full,
        std,
        list(ls.redundant),
        float(np.linalg.norm(resid) / denom) if denom else np.inf,
        resid,
        data,
        ls.delay,
        ls.search,
        "oe",
        why,
        None,
        position_rms=[float(x) for x in np.sqrt(np.mean(res**2, axis=(0, 1)))],
        position_rel=_rel(res, w),
        start=label,
        compared=(other or ls).method,
        compared_position_rel=compared,
        window_s=float(w.size * data.dt),
        windows=int(len(w.starts)),
        iterations=int(its),
        evaluations=problem.evaluations,
    )
