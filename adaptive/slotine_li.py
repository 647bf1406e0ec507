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

from typing import Any, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from manus.adaptive.composite import Composite, CompositeState, _upper, symmetric
from manus.adaptive.projection import Projection
from manus.adaptive.regressors import DEFAULT_BOUNDARY, Regressor
from manus import estimators
from manus.estimators.base import Estimator, run
from manus.plants.effects import Model
from manus.plants.errors import ManusError
from manus.plants.stepper import Controller, Plant, Reference, RefSample
from manus.plants.structures import Manus2

THESIS_RIGID_GAINS = (0.2, 0.2, 0.5)  # Γ1, Γ2, Γ3 for a1, a2, a3 (thesis App. C)
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


def default_gains(model: Model) -> np.ndarray:
    """Γ (P,): the thesis's for MANUS-2's a1, a2, a3, each effect's own `gain` otherwise
    [units of the parameter² per (N·m·rad)]."""
    gamma = np.array([e.gain for e in model.effects for _ in e.names(model.structure)], float)
    if isinstance(model.structure, Manus2) and model.has("rigid"):
        for name, g in zip(model.structure.rigid_names, THESIS_RIGID_GAINS):
            gamma[model.names.index(name)] = g
    return gamma


_run = eqx.filter_jit(run)  # compiled once per kind of estimator


def _model_based(estimator: Estimator) -> bool:
    """Whether `estimator` predicts with a plant model whose parameters it takes (`with_params`)."""
    return hasattr(estimator, "with_params") and getattr(estimator, "dynamics", None) is not None


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


def _per(what: str, value, names: tuple[str, ...], default=None) -> np.ndarray:
    """A per-item vector from None (default), a scalar, a sequence or a {name: value} dict."""
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
        out = np.broadcast_to(np.asarray(value, float), np.shape(default)).copy() if np.ndim(value) == 0 \
            else np.asarray(value, float)
        if out.shape != np.shape(default):
            raise ManusError(f"{what}: expected {len(names)} values ({', '.join(names)}), got shape {out.shape}")
    return out


def _positive(what: str, x: np.ndarray, names: tuple[str, ...]) -> np.ndarray:
    bad = [f"{names[i]}={x[i]:g}" for i in range(x.size) if not (np.isfinite(x[i]) and x[i] > 0)]
    if bad:
        raise ManusError(f"gain {what} must be positive definite (every diagonal entry finite and > 0): "
                         f"{', '.join(bad)}")
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

    def __init__(self, model: Model, dt: float = 1e-3, estimator: Estimator | None = None, *, gamma=None,
                 lam=LAMBDA, kd=KD, theta0=None, form: str = "slotine-li", boundary: float = DEFAULT_BOUNDARY,
                 project: bool = True, min_inertia: float = 1e-3, composite: Composite | None = None,
                 lead: float | None = None, velocity_lag: float | None = None, limit: float = LIMIT):
        self.regressor = Regressor(model, form, boundary)
        names, joints = model.names, tuple(f"joint{i + 1}" for i in range(model.n_joints))
        if not dt > 0:
            raise ManusError(f"control period dt must be positive, got {dt}")
        self.estimator = estimators.make(DEFAULT_ESTIMATOR, dt) if estimator is None else estimator
        if not isinstance(self.estimator, Estimator):
            raise ManusError(f"estimator must be a manus.estimators.base.Estimator, not {type(self.estimator).__name__}")
        if not np.isclose(self.estimator.dt, dt):
            raise ManusError(f"the velocity estimator runs at dt = {self.estimator.dt:g} s but the controller "
                             f"at {dt:g} s")
        self.gamma = jnp.asarray(_positive("gamma", _per("gamma", gamma, names, default_gains(model)), names))
        self.lam = jnp.asarray(_positive("lam", _per("lam", lam, joints, [LAMBDA] * len(joints)), joints))
        self.kd = jnp.asarray(_positive("kd", _per("kd", kd, joints, [KD] * len(joints)), joints))
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

    def init(self, q0: Array) -> SlotineLiState:
        q0 = jnp.asarray(q0, float)
        n, P = self.n_joints, len(self.names)
        if q0.shape != (n,):
            raise ManusError(f"the controller's model {self.regressor.model.spec!r} has {n} joint(s) but the "
                             f"plant measures {q0.shape[-1] if q0.ndim else 1}")
        zeros = jnp.zeros(n)
        comp = self.composite.init(self.regressor, self.gamma) if self.composite is not None else None
        theta0 = self.theta0 if self.projection is None else self.projection(self.theta0, self.gamma)
        return SlotineLiState(self.estimator.init(q0), theta0, zeros, zeros, zeros,
                              jnp.zeros((n, P)), comp, jnp.array(False),
                              jnp.array(0), zeros)

    def _feed(self, est_state, theta):
        """A model-based estimator gets the current estimates of the parameters its model shares
        with the controller's, every tick."""
        if not _model_based(self.estimator):
            return est_state
        model = self.estimator.dynamics.model
        shared = {k: theta[i] for i, k in enumerate(self.names) if k in model.names}
        return self.estimator.with_params(est_state, shared) if shared else est_state

    def step(self, state: SlotineLiState, q: Array, ref: RefSample) -> tuple[SlotineLiState, Array]:
        est_state = self._feed(state.estimator, state.theta)
        est_state, est = self.estimator.step(est_state, q, state.tau)
        v = est.qd + self.velocity_lag * ref.qdd  # the estimate refers to `velocity_lag` s ago
        theta = state.theta
        q_err, v_err = q - ref.q, v - ref.qd
        s = v_err + self.lam * q_err
        # the command acts `lead` s from now: aim the regressor there (reference jerk by differencing)
        jerk = jnp.where(state.ticks > 0, (ref.qdd - state.qdd_ref) / self.dt, 0.0)
        qd_d = ref.qd + self.lead * (ref.qdd + 0.5 * self.lead * jerk)
        qdd_d = ref.qdd + self.lead * jerk
        Y = self.regressor(q + self.lead * v, v, qd_d - self.lam * q_err, qdd_d - self.lam * v_err)
        # Y θ and Yᵀ s as sums of products, not matrix products: under vmap a (2, P) product per
        # trial is a tiny batched matmul, these fuse into the elementwise code
        tau = jnp.clip(jnp.sum(Y * theta, axis=1) - self.kd * s, -self.limit, self.limit)
        grad, comp, metric = jnp.sum(Y * s[:, None], axis=0), state.composite, self.gamma
        if self.composite is None:
            direction = self.gamma * grad
        else:
            comp, W, tau_f = self.composite.step(comp, self.regressor, q, v, tau, self.gamma, self.lead, self.dt)
            direction = self.composite.direction(comp, grad, W, tau_f, theta)
            metric = comp.diagonal
        new_theta = theta - self.dt * direction
        if self.projection is not None:
            new_theta = self.projection(new_theta, metric)
        finite = jnp.all(jnp.isfinite(q)) & jnp.all(jnp.isfinite(v)) & jnp.all(jnp.isfinite(tau)) \
            & jnp.all(jnp.isfinite(new_theta))
        stopped = state.stopped | ~finite
        tau = jnp.where(stopped, 0.0, tau)
        theta = jnp.where(stopped, theta, new_theta)
        return SlotineLiState(est_state, theta, tau, v, s, Y, comp, stopped, state.ticks + 1, ref.qdd), tau


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
    return tuple(jnp.zeros((), dtype) for _ in _upper(m))


def _gram_step(gram: tuple, Y: Array, dt: float) -> tuple:
    """∫YᵀY dt one tick on, entry by entry (upper triangle) from the tick's Y (n, P): sums of
    products of scalars (under vmap a (P, n) × (n, P) product per trial is a tiny batched matmul,
    and a (P, P) broadcast-and-sum took as long as the whole controller, measured)."""
    n, m = Y.shape
    Yt = jnp.moveaxis(Y, -1, 0)  # the parameter axis first: each column a contiguous batch vector
    return tuple(g + dt * sum(Yt[i, a] * Yt[j, a] for a in range(n)) for g, (i, j) in zip(gram, _upper(m)))


def rollout(plant: Plant, controller: SlotineLi, reference: Reference, steps: int, key=None,
            every: int = 50) -> tuple[Log, Array]:
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
        cstate, u = controller.step(cstate, q, ref)
        _, qd_true = plant.truth(pstate)
        pstate, q_next = plant.step(pstate, u)
        gram = _gram_step(gram, cstate.Y, plant.dt)
        return (pstate, cstate, q_next, gram), Log(t, q, ref.q, u, cstate.qd, qd_true, cstate.theta, cstate.stopped)

    def chunk(carry, ks):
        carry, log = jax.lax.scan(tick, carry, ks)
        return carry, (log, carry[3])

    ks = jnp.arange(steps).reshape(steps // every, every)
    _, (log, grams) = jax.lax.scan(chunk, (pstate, cstate, q, _gram_start(P, q.dtype)), ks)
    return jax.tree.map(lambda x: x.reshape((steps,) + x.shape[2:]), log), symmetric(grams, 1)


class BatchLog(NamedTuple):
    """What `rollout_batch` records: numpy arrays with a leading trial axis B (views of arrays
    stored batch-last, as the compiled batch writes them)."""

    t: np.ndarray  # (T,)
    q_err: np.ndarray  # q − q_d (B, T, n)
    tau: np.ndarray  # commands (B, T, n)
    theta: np.ndarray  # estimates â after each tick (B, T, P)
    stopped: np.ndarray  # the controller stopped itself by the end (B,)
    grams: np.ndarray  # ∫₀ᵗ YᵀY dt at every `every`-th tick (B, T // every, P, P)


def rollout_batch(plant: Plant, controller: SlotineLi, reference: Reference, per_trial: tuple, keys: Array,
                  steps: int, every: int = 50) -> BatchLog:
    """Many `rollout`s at once: trial i runs `controller` with per_trial = (â(0), Γ, Λ, K_D), each
    with a leading trial axis, and the plant's noise key keys[i]. Compiled once per kind of plant,
    controller, reference and length.

    As `manus.plants.closed_loop.simulate_batch` does: the trials are vmapped inside the time scan
    (every per-trial scalar a batch vector), the record is written batch-last (each tick writes
    whole rows), and when the number of trials divides the number of devices they are split over
    them (`shard_map`; one device per CPU core, see `manus.runs.cli`)."""
    if steps % every:
        raise ManusError(f"rollout: {steps} steps is not a multiple of every={every}")
    t, q_err, tau, theta, stopped, grams = _batch(plant, controller, reference, tuple(per_trial), keys, int(steps),
                                                  int(every))
    return BatchLog(np.asarray(t), *(np.moveaxis(np.asarray(x), -1, 0) for x in (q_err, tau, theta, stopped, grams)))


@eqx.filter_jit
def _batch(plant, controller, reference, per_trial, keys, steps: int, every: int):
    P = len(controller.names)

    def run(plant, controller, reference, per_trial, keys):
        def start(arrays, key):  # the controller of one trial (its own â(0), Γ, Λ, K_D) and its carry
            c = eqx.tree_at(lambda c: (c.theta0, c.gamma, c.lam, c.kd), controller, arrays)
            pstate, q = plant.reset(key, q0=reference(0.0).q)
            return c, (pstate, c.init(q), q, _gram_start(P, q.dtype))

        def tick(c, carry, k):
            pstate, cstate, q, gram = carry
            ref = reference(k * plant.dt)
            cstate, u = c.step(cstate, q, ref)
            pstate, q_next = plant.step(pstate, u)
            gram = _gram_step(gram, cstate.Y, plant.dt)
            return (pstate, cstate, q_next, gram), (q - ref.q, u, cstate.theta)

        # the whole controller per trial (measured: faster than sharing its constant arrays, whose
        # small products with per-trial vectors then become matrix-library calls)
        ticks = jax.vmap(tick, in_axes=(0, 0, None), out_axes=(0, -1))
        cs, carry = jax.vmap(start)(per_trial, keys)

        def chunk(carry, ks):
            carry, rows = jax.lax.scan(lambda carry, k: ticks(cs, carry, k), carry, ks)
            return carry, (rows, carry[3])

        ks = jnp.arange(steps).reshape(steps // every, every)
        carry, (rows, grams) = jax.lax.scan(chunk, carry, ks)
        rows = jax.tree.map(lambda x: x.reshape((steps,) + x.shape[2:]), rows)
        return (*rows, carry[1].stopped, symmetric(grams, 1))  # batch-last: grams (C, P, P, B)

    devices = jax.devices()
    t = jnp.arange(steps) * plant.dt
    if len(devices) < 2 or keys.shape[0] % len(devices):
        return (t, *run(plant, controller, reference, per_trial, keys))
    Ps = jax.sharding.PartitionSpec
    arrays, rest = eqx.partition((plant, controller, reference), eqx.is_array)
    out = (Ps(None, None, "trials"),) * 3 + (Ps("trials"), Ps(None, None, None, "trials"))
    # no collectives inside: every device runs its own trials
    local = jax.shard_map(lambda arrays, per_trial, keys: run(*eqx.combine(arrays, rest), per_trial, keys),
                          mesh=jax.sharding.Mesh(np.array(devices), ("trials",)),
                          in_specs=(Ps(), Ps("trials"), Ps("trials")), out_specs=out, check_vma=False)
    return (t, *local(arrays, per_trial, keys))


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
