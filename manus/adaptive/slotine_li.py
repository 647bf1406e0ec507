"""The Slotine–Li adaptive controller (thesis App. C; Slotine and Li 1987), as a stepper.

Each control tick (period T), from the measured position q and the reference (q_d, q̇_d, q̈_d):

    v̂           = the velocity estimator's estimate of q̇ (any `manus.estimators.base.Estimator`)
    q̃ = q − q_d,  s = (v̂ − q̇_d) + Λ q̃              tracking error (rad/s)
    q̇_r = q̇_d − Λ q̃,  q̈_r = q̈_d − Λ (v̂ − q̇_d)      reference velocity and acceleration
    τ = Y â − K_D s                                   command [N·m], clipped to ±`limit`
    â ← P(â − T Γ (Yᵀ s [+ κ Wᵀ e]))                  forward Euler at the control rate, projected

Y = Y(q, v̂, q̇_r, q̈_r) is `manus.adaptive.regressors.Regressor` (Slotine–Li or the thesis's form,
friction columns at q̇_r), P the projection of `manus.adaptive.projection` (H(q) positive definite,
friction ≥ 0; optional), and the bracketed term the prediction error of composite adaptation
(`manus.adaptive.composite`; optional). The command uses the estimate â of this tick, before it is
updated. Signs: positive torque accelerates the joint positively; q̃ > 0 means ahead of the
reference.

Defaults are the thesis's (App. C): Γ = diag(0.2, 0.2, 0.5) for a1, a2, a3, Λ = 5 /s,
K_D = 5 N·m·s/rad. Gains of the other parameters (each effect's `gain`) were chosen like the thesis chose Γ,
for the fastest convergence on the complex trajectory (C.13–C.14): the adaptation rate of a
parameter scales with γ_i times the mean square of its column, and the friction columns
(|sgn| = 1, |q̇_r| ≈ 1 rad/s) are about ten times smaller than the acceleration columns
(|q̈_r| ≈ 10 rad/s²): their gains are 25 times larger (5). Four times more again made the
friction estimates of the gradient law ring and drift (up to +16 % on Fc1 in the mean of 20 trials)
and let the composite law's early transient throw some trials far off (measured). The velocity estimator defaults to the
constant-velocity Kalman filter (`kalman_cv`): the thesis used the first difference, which works
with the gradient law but is too noisy for composite adaptation (`manus.adaptive.composite`).

Timing. A sampled loop is late twice, and both biases the estimates, not only the tracking:

- the command acts over the coming period (zero-order hold: on average T/2 later), plus any
  amplifier delay d. A torque late by δ = T/2 + d looks to the adaptation like negative damping:
  the viscous estimate settles near b − δ a ω² (−12 % for b1 on the complex trajectory with
  δ = 0.5 ms, −25 % at 1 ms, measured). `lead` = δ (default T/2) aims the regressor at the
  moment the command acts: the reference is advanced by δ (its jerk from the last two samples)
  and the position by δ v̂.
- the velocity estimate trails the truth by its lag ℓ (T/2 for the first difference, 1/λ ≈
  5.3 ms for the thesis's filtered one), which biases the inertias upward by about K_D ℓ / a
  (+5 % for a1 with the filtered first difference, measured). `velocity_lag` = ℓ (default:
  measured from the estimator, `measure_lag`) is made up with the reference acceleration:
  v = v̂ + ℓ q̈_d. `lead=0, velocity_lag=0` gives the thesis's uncompensated controller.

Safety: a non-finite velocity estimate, measurement, command or estimate stops the controller
for good: zero torque from that tick on, the estimates frozen at their last finite values, the
run (and its data) carried on by whoever runs the loop.

The same object runs in the JAX simulator (`manus.plants.closed_loop`, or `rollout` below, which also
logs the estimates), over recorded positions (`replay`), and jitted once in a real-time loop.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import PartitionSpec

from manus import estimators
from manus.adaptive.composite import Composite, CompositeState, symmetric, upper_triangle
from manus.adaptive.projection import Projection
from manus.adaptive.regressors import DEFAULT_BOUNDARY, Regressor
from manus.estimators.base import Estimator, run
from manus.plants.devices import BATCH, split
from manus.plants.effects import Model
from manus.plants.errors import ManusError
from manus.plants.stepper import Controller, Plant, Reference, RefSample

LAMBDA, KD = 5.0, 5.0  # Λ [1/s], K_D [N·m·s/rad] (thesis App. C)
DEFAULT_ESTIMATOR = "kalman_cv"  # see the module docstring
LIMIT = 22.2  # N·m: the D/A and amplifier chain's largest torque (manus.plants.simulator.Actuator)


class SlotineLiState(NamedTuple):
    estimator: Any  # the velocity estimator's state
    theta: Array  # â (P,)
    tau: Array  # the last command (n,)
    qd: Array  # the last velocity estimate (n,)
    s: Array  # the last tracking error s (n,)
    Y: Array  # the last regressor (n, P)
    composite: CompositeState | None
    stopped: Array  # bool: latched by a non-finite value
    ticks: Array  # ticks since init
    qdd_ref: Array  # the reference acceleration of the last tick (n,)


KD_BANDWIDTH = 14.0  # [rad/s] K_D/H of the thesis's gains on MANUS-2 (K_D = 5 on H ≈ 0.35 kg m²)


def default_kd(model: Model) -> list[float]:
    """K_D per joint: the thesis's 5 N·m·s/rad on MANUS-2 and single axes; on a serial chain
    `KD_BANDWIDTH` times each joint's own inertia (`Structure.nominal_joint_inertias`: the URDF's
    H(0) diagonal), since a fixed 5 on a light link is a loop far faster than the sample rate allows
    (measured: the DFKI pendulum's elbow, H = 0.027 kg m², diverged at 250 Hz with 5 and tracked
    within 1 mrad with 0.37)."""
    inertias = model.structure.nominal_joint_inertias()
    if inertias is None:
        return [KD] * model.n_joints
    return (KD_BANDWIDTH * np.maximum(inertias, 1e-9)).tolist()


def default_gains(model: Model) -> np.ndarray:
    """Γ (P,): each effect's own `gain` [units of the parameter² per (N·m·rad)], and the rigid
    parameters' where the structure has its own (`Structure.rigid_gains`: the thesis's for
    MANUS-2's a1, a2, a3; a serial chain's in pseudo-inertia coordinates in the pattern of its
    projection's metric)."""
    gamma = np.array([e.gain for e in model.effects for _ in e.names(model.structure)], float)
    rigid = model.get("rigid")
    if rigid is not None:
        for name, g in model.structure.rigid_gains(rigid.gain).items():
            gamma[model.names.index(name)] = g
    return gamma


_run = eqx.filter_jit(run)  # compiled once per kind of estimator


def _model_based(estimator: Estimator) -> bool:
    """Whether `estimator` predicts with a plant model whose parameters it takes (`with_params`)."""
    return estimator.model is not None


def measure_lag(estimator: Estimator, n_joints: int, seconds: float = 2.0) -> float:
    """ℓ [s]: how far `estimator`'s velocity trails the truth at low frequency, measured on a
    constant-acceleration ramp q = t²/2 (true velocity t) once its start-up has died out:
    T/2 for the first difference, about 1/λ for the filtered one, 0 for a constant-acceleration
    Kalman filter. (Not for model-based estimators: with no torque on the ramp their model is
    wrong; `SlotineLi` takes their lag as 0.)"""
    t = np.arange(int(round(seconds / estimator.dt))) * estimator.dt
    q = np.repeat(0.5 * t[:, None] ** 2, n_joints, axis=1)
    lag = t[-1] - float(_run(estimator, q).qd[-1, 0])
    return lag if np.isfinite(lag) and 0 <= lag < 0.1 else 0.0


def _per(what: str, value, names: tuple[str, ...], default: Sequence[float] | np.ndarray) -> np.ndarray:
    """A per-item vector from None (`default`), a scalar, a sequence or a {name: value} dict."""
    if value is None:
        out = np.array(default, float)
    elif isinstance(value, dict):
        unknown = sorted(set(value) - set(names))
        if unknown:
            raise ManusError(f"{what}: unknown name(s) {', '.join(unknown)} (expected {', '.join(names)})")
        out = np.array(default, float)
        for k, v in value.items():
            out[names.index(k)] = v
    else:
        out = (
            np.broadcast_to(np.asarray(value, float), np.shape(default)).copy()
            if np.ndim(value) == 0
            else np.asarray(value, float)
        )
        if out.shape != np.shape(default):
            raise ManusError(f"{what}: expected {len(names)} values ({', '.join(names)}), got shape {out.shape}")
    return out


def _positive(what: str, x: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    bad = [f"{names[i]}={x[i]:g}" for i in range(x.size) if not (np.isfinite(x[i]) and x[i] > 0)]
    if bad:
        raise ManusError(
            f"gain {what} must be positive definite (every diagonal entry finite and > 0): {', '.join(bad)}"
        )
    return x


def _delay(what: str, value) -> float:
    if not (np.isfinite(value) and 0 <= value < 0.1):
        raise ManusError(f"{what} must be a time in [0, 0.1) s, got {value}")
    return float(value)


class SlotineLi(Controller):
    """The adaptive controller (see the module docstring). Build it with the keyword gains;
    every array field may carry a leading batch axis for vmapped trials."""

    regressor: Regressor
    estimator: Estimator
    gamma: Array  # Γ diagonal (P,)
    lam: Array  # Λ diagonal (n,) [1/s]
    kd: Array  # K_D diagonal (n,) [N·m·s/rad]
    theta0: Array  # initial estimate â(0) (P,)
    projection: Projection | None
    composite: Composite | None
    lead: float  # δ [s]: from the measurement to the middle of the period the command acts over
    velocity_lag: float  # ℓ [s]: how far the velocity estimate trails the true velocity
    limit: float  # |τ| ≤ limit [N·m]
    dt: float = eqx.field(static=True)

    def __init__(
        self,
        model: Model,
        dt: float = 1e-3,
        estimator: Estimator | None = None,
        *,
        gamma=None,
        lam=LAMBDA,
        kd=None,
        theta0=None,
        form: str = "slotine-li",
        boundary: float = DEFAULT_BOUNDARY,
        project: bool = True,
        min_inertia: float = 1e-3,
        composite: Composite | None = None,
        lead: float | None = None,
        velocity_lag: float | None = None,
        limit: float = LIMIT,
    ):
        self.regressor = Regressor(model, form, boundary)
        names, joints = model.names, tuple(f"joint{i + 1}" for i in range(model.n_joints))
        if not dt > 0:
            raise ManusError(f"control period dt must be positive, got {dt}")
        self.estimator = estimators.make(DEFAULT_ESTIMATOR, dt) if estimator is None else estimator
        if not isinstance(self.estimator, Estimator):
            raise ManusError(
                f"estimator must be a manus.estimators.base.Estimator, not {type(self.estimator).__name__}"
            )
        if not np.isclose(self.estimator.dt, dt):
            raise ManusError(
                f"the velocity estimator runs at dt = {self.estimator.dt:g} s but the controller at {dt:g} s"
            )
        self.gamma = jnp.asarray(_positive("gamma", _per("gamma", gamma, names, default_gains(model)), names))
        self.lam = jnp.asarray(_positive("lam", _per("lam", lam, joints, [LAMBDA] * len(joints)), joints))
        self.kd = jnp.asarray(_positive("kd", _per("kd", kd, joints, default_kd(model)), joints))
        defaults = model.defaults()
        theta = _per("theta0", theta0, names, [defaults[k] for k in names])
        if not np.all(np.isfinite(theta)):
            raise ManusError("theta0: initial estimates must be finite")
        self.theta0 = jnp.asarray(theta)
        self.lead = _delay("lead", 0.5 * dt if lead is None else lead)
        if velocity_lag is None:  # a model-based estimator has no lag while its model holds
            velocity_lag = 0.0 if _model_based(self.estimator) else measure_lag(self.estimator, model.n_joints)
        self.velocity_lag = _delay("velocity_lag", velocity_lag)
        self.projection = Projection(model, min_inertia) if project else None
        self.composite = composite
        if not limit > 0:
            raise ManusError(f"torque limit must be positive, got {limit}")
        self.limit = float(limit)
        self.dt = float(dt)

    @property
    def names(self) -> tuple[str, ...]:
        return self.regressor.names

    @property
    def n_joints(self) -> int:
        return self.regressor.n_joints

    def velocity(self, state: SlotineLiState) -> Array:
        return state.qd

    def stopped(self, state: SlotineLiState) -> Array:
        return state.stopped

    def init(self, q0: Array) -> SlotineLiState:
        q0 = jnp.asarray(q0, float)
        n, P = self.n_joints, len(self.names)
        if q0.shape != (n,):
            raise ManusError(
                f"the controller's model {self.regressor.model.spec!r} has {n} joint(s) but the "
                f"plant measures {q0.shape[-1] if q0.ndim else 1}"
            )
        zeros = jnp.zeros(n)
        comp = self.composite.init(self.regressor, self.gamma) if self.composite is not None else None
        theta0 = self.theta0 if self.projection is None else self.projection(self.theta0, self.gamma)
        return SlotineLiState(
            self.estimator.init(q0),
            theta0,
            zeros,
            zeros,
            zeros,
            jnp.zeros((n, P)),
            comp,
            jnp.array(False),
            jnp.array(0),
            zeros,
        )

    def _feed(self, est_state, theta):
        """A model-based estimator gets the current estimates of the parameters its model shares
        with the controller's, every tick."""
        model = self.estimator.model
        if model is None:
            return est_state
        shared = {k: theta[i] for i, k in enumerate(self.names) if k in model.names}
        return self.estimator.with_params(est_state, shared) if shared else est_state

    def step(self, state: SlotineLiState, q: Array, ref: RefSample) -> tuple[SlotineLiState, Array]:
        state, tau, _ = self._step(state, q, ref)
        return state, tau

    def _step(self, state: SlotineLiState, q: Array, ref: RefSample):
        """`step`, and the tick's Y entry by entry (nested lists [joint][parameter] of scalars).

        Written on per-joint and per-parameter scalars throughout (Y θ and Yᵀ s as sums of
        products, not matrix products or reductions over the (n, P) array): under vmap each is a
        batch vector and the whole step elementwise code on them, where the array forms become
        tiny batched products, short strided reductions and transposes per trial
        (docs/performance.md)."""
        est_state = self._feed(state.estimator, state.theta)
        est_state, est = self.estimator.step(est_state, q, state.tau)
        n, m, lead = self.n_joints, len(self.names), self.lead
        J = range(n)
        per = lambda x: [x[a] for a in J]
        qj, qdj, qddj, qdd_prev = per(q), per(ref.qd), per(ref.qdd), per(state.qdd_ref)
        lam, kd = per(self.lam), per(self.kd)
        v = [
            x + self.velocity_lag * a for x, a in zip(per(est.qd), qddj, strict=True)
        ]  # the estimate is `velocity_lag` s old
        q_err = [x - d for x, d in zip(qj, per(ref.q), strict=True)]
        v_err = [x - d for x, d in zip(v, qdj, strict=True)]
        s = [ev + l * e for ev, l, e in zip(v_err, lam, q_err, strict=True)]
        # the command acts `lead` s from now: aim the regressor there (reference jerk by differencing)
        started = state.ticks > 0
        jerk = [jnp.where(started, (a - b) / self.dt, 0.0) for a, b in zip(qddj, qdd_prev, strict=True)]
        qd_r = [
            d + lead * (a + 0.5 * lead * j) - l * e for d, a, j, l, e in zip(qdj, qddj, jerk, lam, q_err, strict=True)
        ]
        qdd_r = [a + lead * j - l * ev for a, j, l, ev in zip(qddj, jerk, lam, v_err, strict=True)]
        Y = regressor_entries(
            self.regressor,
            jnp.stack([x + lead * w for x, w in zip(qj, v, strict=True)]),
            jnp.stack(v),
            jnp.stack(qd_r),
            jnp.stack(qdd_r),
        )
        Y, s = fusion_boundary((Y, s))  # each entry computed once (see fusion_boundary)
        th = [state.theta[k] for k in range(m)]
        tau = [jnp.clip(sum(Y[a][k] * th[k] for k in range(m)) - kd[a] * s[a], -self.limit, self.limit) for a in J]
        grad = [sum(Y[a][k] * s[a] for a in J) for k in range(m)]
        comp, metric, gamma = state.composite, self.gamma, [self.gamma[k] for k in range(m)]
        if self.composite is None:
            new_theta = jnp.stack([t - self.dt * g * d for t, g, d in zip(th, gamma, grad, strict=True)])
        else:
            assert comp is not None  # (init gives a composite controller its state)
            comp, W, tau_f = self.composite.step(
                comp, self.regressor, q, jnp.stack(v), jnp.stack(tau), self.gamma, lead, self.dt
            )
            new_theta = state.theta - self.dt * self.composite.direction(comp, jnp.stack(grad), W, tau_f, state.theta)
            metric = comp.diagonal
        if self.projection is not None:
            new_theta = self.projection(new_theta, metric)
        finite = jnp.all(jnp.isfinite(new_theta))
        for x in (*qj, *v, *tau):
            finite = finite & jnp.isfinite(x)
        stopped = state.stopped | ~finite
        tau = jnp.stack([jnp.where(stopped, 0.0, x) for x in tau])
        theta = jnp.where(stopped, state.theta, new_theta)
        Ya = jnp.stack([jnp.stack(row) for row in Y])
        return (
            SlotineLiState(
                est_state, theta, tau, jnp.stack(v), jnp.stack(s), Ya, comp, stopped, state.ticks + 1, ref.qdd
            ),
            tau,
            Y,
        )


def fusion_boundary(tree):
    """`tree` unchanged; under vmap, computed once and read by every consumer.

    XLA on the CPU fuses cheap elementwise work into each consumer, re-computing it there: a
    value read by ten fusions is computed ten times (Y's entries and s feed τ, Yᵀ s, the new
    estimates and ∫YᵀY: 297 -> 194 ns CPU per trial-step in the convergence batch without the
    repeats, measured). A conditional is a boundary fusion does not cross, and the batch's
    branches once on one trial's value (the first entry equal to itself: always, but XLA cannot
    tell); the other branch returns the same values (NaN stays NaN) in a form XLA does not
    recognize as the same, so it keeps the conditional. One trial (no vmap): nothing."""

    @jax.custom_batching.custom_vmap
    def same(leaves):
        return leaves

    @same.def_vmap
    def same_batched(axis_size, in_batched, leaves):
        leaves = [
            x if b else jnp.broadcast_to(x, (axis_size,) + x.shape) for x, b in zip(leaves, in_batched[0], strict=True)
        ]
        first = leaves[0].ravel()[0]
        out = jax.lax.cond(
            first == first, lambda xs: list(xs), lambda xs: [jnp.where(x == x, x, x + 1) for x in xs], leaves
        )
        return out, [True] * len(out)

    leaves, treedef = jax.tree.flatten(tree)
    return jax.tree.unflatten(treedef, same(leaves))


def regressor_entries(regressor: Regressor, q, qd, qd_r, qdd_r) -> list[list]:
    """`regressor`(q, q̇, q̇_r, q̈_r) entry by entry: nested lists [joint][parameter] of scalars,
    equal to the (n, P) array. In the Slotine–Li form the rigid columns a structure writes out
    (`Structure.slotine_li_columns`: MANUS-2's, as `Regressor.__call__` takes them) are its own;
    every other effect's column is its torque with that parameter 1 and the rest 0 (each effect is
    linear in its parameters: the column exactly, what forward-mode differentiation computes);
    other structures and forms: the array's entries."""
    model, names = regressor.model, regressor.names
    s, n = model.structure, regressor.n_joints
    columns = s.slotine_li_columns(q, qd, qd_r, qdd_r) if regressor.form == "slotine-li" else None
    if columns is None:
        Y = regressor(q, qd, qd_r, qdd_r)
        return [[Y[a, k] for k in range(len(names))] for a in range(n)]
    for e in model.effects:
        if e.inertial:
            continue
        for k in e.names(s):
            unit = {name: 1.0 if name == k else 0.0 for name in names}
            col = model.effect_torque(e, q, qd_r, qdd_r, unit, regressor.boundary)
            columns[k] = tuple(col[a] for a in range(n))
    return [[columns[k][a] for k in names] for a in range(n)]


class Log(NamedTuple):
    """What `rollout` records per tick: arrays (T, ...)."""

    t: Array
    q: Array  # measured positions (n,)
    q_ref: Array
    tau: Array  # commands (n,)
    qd: Array  # velocity estimates (n,)
    qd_true: Array
    theta: Array  # estimates â after the tick (P,)
    stopped: Array


def _gram_start(m: int, dtype) -> tuple:
    """∫₀⁰ YᵀY dt, entry by entry: the upper triangle of an m×m zero matrix, row by row."""
    return tuple(jnp.zeros((), dtype) for _ in upper_triangle(m))


def _gram_step(gram: tuple, Y: list, dt: float) -> tuple:
    """∫YᵀY dt one tick on, entry by entry (upper triangle) from the tick's Y as nested lists
    [joint][parameter] of scalars (`regressor_entries`): sums of products of scalars (under vmap
    a (P, n) × (n, P) product per trial is a tiny batched matmul, and a (P, P) broadcast-and-sum
    took as long as the whole controller, measured)."""
    n, m = len(Y), len(Y[0])
    return tuple(
        g + dt * sum(Y[a][i] * Y[a][j] for a in range(n)) for g, (i, j) in zip(gram, upper_triangle(m), strict=True)
    )


def rollout(
    plant: Plant, controller: SlotineLi, reference: Reference, steps: int, key=None, every: int = 50
) -> tuple[Log, Array]:
    """`steps` closed-loop ticks in one `lax.scan` (pure: jit and vmap go through), logging the
    estimates -> (Log, G): G (steps // every, P, P) holds ∫₀ᵗ YᵀY dt at every `every`-th tick,
    the excitation the adaptation has seen so far (its smallest eigenvalue: how well the
    least-excited combination of parameters is determined)."""
    if steps % every:
        raise ManusError(f"rollout: {steps} steps is not a multiple of every={every}")
    pstate, q = plant.reset(key, q0=reference(0.0).q)
    cstate = controller.init(q)
    P = len(controller.names)

    def tick(carry, k):
        pstate, cstate, q, gram = carry
        t = k * plant.dt
        ref = reference(t)
        cstate, u, Y = controller._step(cstate, q, ref)
        _, qd_true = plant.truth(pstate)
        pstate, q_next = plant.step(pstate, u)
        gram = _gram_step(gram, Y, plant.dt)
        return (pstate, cstate, q_next, gram), Log(t, q, ref.q, u, cstate.qd, qd_true, cstate.theta, cstate.stopped)

    def chunk(carry, ks):
        carry, log = jax.lax.scan(tick, carry, ks)
        return carry, (log, carry[3])

    ks = jnp.arange(steps).reshape(steps // every, every)
    _, (log, grams) = jax.lax.scan(chunk, (pstate, cstate, q, _gram_start(P, q.dtype)), ks)
    return jax.tree.map(lambda x: x.reshape((steps,) + x.shape[2:]), log), symmetric(grams, 1)


TOLERANCE = 0.05  # the trials' settling band: |â − a| ≤ 5 % of |a|


class BatchLog(NamedTuple):
    """What `rollout_batch` returns: numpy arrays with a leading trial axis B (views of arrays
    stored batch-last, as the compiled batch writes them). The statistics cover every tick; the
    record keeps every `record`-th tick (the last of each `record`), for figures."""

    t: np.ndarray  # times of the recorded ticks (T // record,)
    q_err: np.ndarray  # q − q_d at the recorded ticks (B, T // record, n)
    tau: np.ndarray  # commands at the recorded ticks (B, T // record, n)
    theta: np.ndarray  # estimates â after the recorded ticks (B, T // record, P)
    stopped: np.ndarray  # the controller stopped itself by the end (B,)
    grams: np.ndarray  # ∫₀ᵗ YᵀY dt at every `every`-th tick (B, T // every, P, P)
    theta_final: np.ndarray  # â after the last tick (B, P)
    q_err_ms: np.ndarray  # mean of (q − q_d)² over every tick (B, n)
    tau_max: np.ndarray  # largest |τ| over every tick (B, n)
    settle: np.ndarray  # the time after which |â − a| ≤ TOLERANCE |a| for good, NaN if never (B, P)


def _trial_steps(plant: Plant, reference: Reference, truth: Array):
    """(start, tick) of one trial, as `rollout_batch` and `trial` run it: the carry is the plant's
    and controller's states, the measurement, ∫YᵀY dt entry by entry (`_gram_step`) and the
    statistics of every tick (Σ (q − q_d)², max |τ|, the last tick with â outside its band)."""

    def start(controller: SlotineLi, key):
        pstate, q = plant.reset(key, q0=reference(0.0).q)
        n, m = controller.n_joints, len(controller.names)
        stats = (jnp.zeros(n, q.dtype), jnp.zeros(n, q.dtype), jnp.full(m, -1, jnp.int32))
        return pstate, controller.init(q), q, _gram_start(m, q.dtype), stats

    def tick(controller: SlotineLi, carry, k):
        pstate, cstate, q, gram, (sq, tau_max, last_out) = carry
        ref = reference(k * plant.dt)
        e = q - ref.q
        cstate, u, Y = controller._step(cstate, q, ref)
        pstate, q_next = plant.step(pstate, u)
        out = jnp.abs(cstate.theta - truth) > TOLERANCE * jnp.abs(truth)
        stats = (sq + e * e, jnp.maximum(tau_max, jnp.abs(u)), jnp.where(out, k.astype(jnp.int32), last_out))
        return (pstate, cstate, q_next, _gram_step(gram, Y, plant.dt), stats), (e, u, cstate.theta)

    return start, tick


def _scan_ticks(tick, carry, steps: int, every: int, record: int, gram_of):
    """`steps` ticks of `tick(carry, k) -> (carry, row)` in nested scans: blocks of `record` ticks
    (the row of the last kept), chunks of `every` ticks (`gram_of(carry)` kept at their end)."""

    def block(carry, k0):
        if record > 1:
            carry, _ = jax.lax.scan(lambda c, k: (tick(c, k)[0], None), carry, k0 + jnp.arange(record - 1))
        return tick(carry, k0 + record - 1)

    def chunk(carry, k0):
        carry, rows = jax.lax.scan(block, carry, k0 + record * jnp.arange(every // record))
        return carry, (rows, gram_of(carry))

    carry, (rows, grams) = jax.lax.scan(chunk, carry, every * jnp.arange(steps // every))
    rows = jax.tree.map(lambda x: x.reshape((steps // record,) + x.shape[2:]), rows)
    return carry, rows, grams


def _outputs(carry, rows, grams, steps: int):
    """The per-trial arrays of a finished scan, in `BatchLog` order after t (a trial axis, if
    any, stays last)."""
    _, cstate, _, _, (sq, tau_max, last_out) = carry
    return (*rows, cstate.stopped, symmetric(grams, 1), cstate.theta, sq / steps, tau_max, last_out)


def trial(
    plant: Plant,
    controller: SlotineLi,
    reference: Reference,
    steps: int,
    key: Array,
    truth: Array,
    every: int = 50,
    record: int = 1,
) -> tuple:
    """One trial of `rollout_batch`, unbatched: the same ticks in the same scans (the one-by-one
    baseline of `manus bench converge`) -> its arrays in `BatchLog` order after t, without the trial
    axis, the settle statistic as the last tick outside the band (−1: none)."""
    _check(steps, every, record)
    start, tick = _trial_steps(plant, reference, jnp.asarray(truth))
    carry, rows, grams = _scan_ticks(
        lambda c, k: tick(controller, c, k), start(controller, key), steps, every, record, lambda c: c[3]
    )
    return _outputs(carry, rows, grams, steps)


def _check(steps: int, every: int, record: int) -> None:
    if every < 1 or record < 1 or steps % every or every % record:
        raise ManusError(
            f"rollout: {steps} steps in chunks of every={every} recorded every {record}: need whole multiples"
        )


def rollout_batch(
    plant: Plant,
    controller: SlotineLi,
    reference: Reference,
    per_trial: tuple,
    keys: Array,
    steps: int,
    every: int = 50,
    record: int = 1,
    truth: Array | np.ndarray | Sequence[float] | None = None,
) -> BatchLog:
    """Many closed-loop trials at once: trial i runs `controller` with per_trial = (â(0), Γ, Λ, K_D),
    each with a leading trial axis, and the plant's noise key keys[i]; `truth` (P,) the parameters'
    true values for the settle statistic (default: the plant's, 0 where it has none). Compiled once
    per kind of plant, controller, reference and length.

    As `manus.plants.closed_loop.simulate_batch` does: the trials are vmapped inside the time scan
    (every per-trial scalar a batch vector), and when the number of trials divides the number of
    devices they are split over them (`shard_map`; one device per CPU core, see `manus.runs.cli`).
    The scan carries every entry of every per-trial array as its own batch vector, so that XLA
    has no layout to choose (measured, the whole batch: 215 ns CPU per trial-step with the trial
    axis first, 196 with it last, 190 with every entry apart), and keeps of each tick only the
    statistics (`BatchLog`) and every `record`-th tick's row."""
    _check(steps, every, record)
    if truth is None:
        params = plant.params
        truth = [float(params.get(k, 0.0)) for k in controller.names]
    out = _batch(
        plant,
        controller,
        reference,
        tuple(per_trial),
        keys,
        jnp.asarray(truth, float),
        int(steps),
        int(every),
        int(record),
    )
    *arrays, last_out = (np.moveaxis(np.asarray(x), -1, 0) for x in out)
    settle = np.where(last_out < steps - 1, (last_out + 1) * plant.dt, np.nan)
    t = (np.arange(steps // record) * record + record - 1) * plant.dt
    return BatchLog._make([t, *arrays, settle])


def _entries(tree) -> tuple[tuple, tuple]:
    """A pytree of batch-last arrays (..., B) as a flat tuple of batch vectors (B,), and what
    `_rebuild` needs to put it back."""
    leaves, treedef = jax.tree.flatten(tree)
    return tuple(v for x in leaves for v in x.reshape(-1, x.shape[-1])), (treedef, tuple(x.shape for x in leaves))


def _rebuild(vectors: tuple, spec: tuple):
    """The pytree `_entries` took apart."""
    treedef, shapes = spec
    leaves, i = [], 0
    for shape in shapes:
        size = math.prod(shape[:-1])
        leaves.append(jnp.stack(vectors[i : i + size]).reshape(shape))
        i += size
    return jax.tree.unflatten(treedef, leaves)


@eqx.filter_jit
def _batch(plant, controller, reference, per_trial, keys, truth, steps: int, every: int, record: int):
    def run(plant, controller, reference, per_trial, keys, truth):
        start, tick = _trial_steps(plant, reference, truth)

        def begin(arrays, key):  # the controller of one trial (its own â(0), Γ, Λ, K_D) and its carry
            c = eqx.tree_at(lambda c: (c.theta0, c.gamma, c.lam, c.kd), controller, arrays)
            return c, start(c, key)

        # the whole controller per trial (measured: faster than sharing its constant arrays, whose
        # small products with per-trial vectors then become matrix-library calls), batch-last,
        # every entry its own batch vector (see rollout_batch)
        cs, carry = jax.vmap(begin, out_axes=-1)(per_trial, keys)
        cs, cs_spec = _entries(cs)
        carry, spec = _entries(carry)
        ticks = jax.vmap(tick, in_axes=(-1, -1, None), out_axes=(-1, -1))

        def flat_tick(carry, k):
            carry, row = ticks(_rebuild(cs, cs_spec), _rebuild(carry, spec), k)
            return _entries(carry)[0], row

        carry, rows, grams = _scan_ticks(flat_tick, carry, steps, every, record, lambda c: _rebuild(c, spec)[3])
        return _outputs(_rebuild(carry, spec), rows, grams, steps)

    # every device runs its own trials
    rows, last = PartitionSpec(None, None, BATCH), PartitionSpec(None, BATCH)
    out = (rows, rows, rows, PartitionSpec(BATCH), PartitionSpec(None, None, None, BATCH), last, last, last, last)
    return split(
        lambda whole, parts: run(whole[0], whole[1], whole[2], parts[0], parts[1], whole[3]),
        (plant, controller, reference, truth),
        (per_trial, keys),
        out,
    )


def replay(controller: Controller, q: Array, refs: RefSample) -> tuple[Any, Array]:
    """Run `controller` over recorded positions q (T, n) against reference samples `refs`
    (arrays (T, n) each) in one `lax.scan` -> (its state after every tick, commands (T, n)).
    The controller does not know the difference: a run in the loop and its replay agree."""
    q = jnp.asarray(q, float)

    def body(state, x):
        state, tau = controller.step(state, x[0], RefSample(*x[1:]))
        return state, (state, tau)

    _, (states, tau) = jax.lax.scan(body, controller.init(q[0]), (q, *refs))
    return states, tau
