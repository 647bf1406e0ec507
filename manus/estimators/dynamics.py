"""The plant model inside the model-based estimators (`kalman_model`, `luenberger_model`).

Forward dynamics from the effect vocabulary, nothing re-defined: with the model's torque
τ_model(q, q̇, q̈; θ) = H(q) q̈ + C(q, q̇) q̇ + (the other effects) (`manus.plants.effects.Model.torque`),

    q̈ = H(q)⁻¹ (τ − τ_model(q, q̇, 0; θ))

where τ is the torque acting on the joint over the last period: the command of `delay` samples
before (the model's `delay` effect, rounded to whole periods; none by default). Coulomb-type
friction is set-valued at rest; the prediction uses the model's boundary layer sgn(v) → sat(v/φ)
(`boundary` φ [rad/s or m/s]), smooth enough for a Jacobian.

Parameters θ live in the estimator's *state*, not in its configuration, so that a controller can
hand over its current estimates every tick with a pure function:

    state = estimator.with_params(state, theta)     # θ (P,) in `model.names` order, or a dict

(a dict may name only some parameters; the others keep their values). Everything is pure and
jit/vmap/scan-able.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jax import Array
from jax.typing import ArrayLike

from manus.estimators.base import Estimator
from manus.plants.effects import Delay, Model
from manus.plants.errors import ManusError, ModelError


class ModelDynamics(eqx.Module):
    """q̈ = H⁻¹(τ − τ_model) for one `Model`, with the command delay in whole samples."""

    model: Model
    boundary: float = eqx.field(static=True)  # φ of the friction boundary layer [rad/s or m/s]
    delays: tuple[int, ...] = eqx.field(static=True)  # per joint: samples between a command and the torque it becomes

    def __init__(self, model: Model, dt: float, boundary: float = 0.01):
        if not model.has("rigid"):
            raise ModelError(f"a model-based estimator needs the 'rigid' effect (the inertia): got {model.spec!r}")
        self.model = model
        self.boundary = float(boundary)
        if not self.boundary > 0:
            raise ValueError(f"the friction boundary layer must be positive, got {boundary}")
        d = model.get("delay")
        n = model.n_joints
        if isinstance(d, Delay):
            delays = d.per_joint(n)  # pyright: ignore[reportAttributeAccessIssue] (equinox hides the subclass from narrowing)
            self.delays = tuple(int(round(x / dt)) for x in delays)
        else:
            self.delays = (0,) * n

    @property
    def delay(self) -> int:
        """The longest delay [samples]: how many commands are kept."""
        return max(self.delays)

    def theta(self, params: dict | ArrayLike | None, current: Array | None = None) -> Array:
        """θ (P,) from a full vector, or a dict of some parameters (the rest from `current`, or
        the model's defaults)."""
        names = self.model.names
        if params is None or isinstance(params, dict):
            base = jnp.asarray([self.model.defaults()[k] for k in names], float) if current is None else current
            unknown = sorted(set(params or {}) - set(names))
            if unknown:
                raise ManusError(
                    f"unknown parameter(s) {', '.join(unknown)} for the estimator's model "
                    f"{self.model.spec} (it has {', '.join(names)})"
                )
            for k, v in (params or {}).items():
                base = base.at[names.index(k)].set(v)
            return base
        theta = jnp.asarray(params, float)
        if theta.shape != (len(names),):
            raise ManusError(
                f"parameter vector of shape {theta.shape}: the model {self.model.spec} has "
                f"{len(names)} parameters ({', '.join(names)})"
            )
        return theta

    def commands(self, n: int) -> Array | None:
        """The initial history of commands not yet acting (delay, n): none commanded yet (None
        without a delay)."""
        return jnp.zeros((self.delay, n)) if self.delay else None

    def acting(self, history: Array | None, tau: Array | None, n: int) -> tuple[Array, Array | None]:
        """(torque acting over the last period (n,), new history) given the latest command."""
        tau = jnp.zeros(n) if tau is None else jnp.asarray(tau, float)
        if history is None:
            return tau, None
        full = jnp.concatenate([tau[None], history])
        return jnp.stack([full[d, i] for i, d in enumerate(self.delays)]), full[:-1]

    def acceleration(self, q: Array, qd: Array, tau: Array, theta: Array) -> Array:
        """q̈ (n,) of the model under the applied torque τ (n,)."""
        p = self.model.unvector(theta)
        s = self.model.structure
        rest = self.model.torque(q, qd, jnp.zeros_like(qd), p, boundary=self.boundary)
        return s.solve(s.inertia(q, p), tau - rest)

    def predict(self, q, qd, tau, theta, dt):
        """(q, q̇, q̈): the state one period on, at the model's acceleration q̈ held over the period."""
        a = self.acceleration(q, qd, tau, theta)
        return q + dt * qd + 0.5 * dt * dt * a, qd + dt * a, a


class ModelBased(Estimator):
    """An estimator whose state carries model parameters θ (field `theta`) and a command history
    (field `commands`)."""

    dynamics: eqx.AbstractVar[ModelDynamics | None]

    @property
    def model(self) -> Model | None:
        return None if self.dynamics is None else self.dynamics.model

    def with_params(self, state, params: dict | ArrayLike):
        """The state with the model's parameters replaced: pure, jit-able, once per tick if need be.

        `params`: θ (P,) in the order of `dynamics.model.names` (an adaptive controller's â when
        it adapts the same `Model`), or a dict naming some of them (the rest are kept)."""
        if self.dynamics is None:
            raise ManusError(f"{type(self).__name__} has no model: nothing to set parameters of")
        return state._replace(theta=self.dynamics.theta(params, state.theta))

    def params(self, state) -> dict:
        """The model parameters the state holds, by name."""
        assert self.dynamics is not None, f"{type(self).__name__} has no model"
        return self.dynamics.model.unvector(state.theta)
