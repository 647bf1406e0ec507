"""The controller registry: one way for the command line and the hardware loop to build a
controller by name.

    make_controller("slotine-li", model, dt=1e-3, estimator="kalman_ca", gamma={"a1": 0.3})

- `impedance`: `manus.adaptive.impedance.Impedance`, τ = K (q_d − q) + B (q̇_d − v̂); gains
  stiffness, damping, limit;
- `slotine-li`: `manus.adaptive.slotine_li.SlotineLi`, the gradient law; gains gamma, lam, kd,
  theta0, form, boundary, project, min_inertia, lead, velocity_lag, limit;
- `slotine-li-composite`: the same with composite adaptation (a least-squares gain); the gains of
  slotine-li, plus bandwidth, weight, forgetting.

`estimator` is a `manus.estimators.base.Estimator`, a name in `manus.estimators.NAMES` (a model-based one,
`kalman_model` or `luenberger_model`, is built on the controller's model, and Slotine–Li hands it
its current estimates every tick), or None (each controller's default). Every controller
returned is a `manus.plants.stepper.Controller`.

Beside them, the controllers experiments drive a plant with: `Replay` (a torque schedule played
back, open loop), `PPD` (the EMPS rig's P-PD loop) and `LockedSpring` (the thesis's locked-joint
oscillation tests); and `compiled_tick`, a controller and its reference compiled into the hardware
loop's tick for a device.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from jax import Array

from manus import estimators
from manus.adaptive.composite import Composite
from manus.adaptive.impedance import Impedance
from manus.adaptive.slotine_li import SlotineLi
from manus.estimators.base import Estimator, FilteredFirstDifference
from manus.plants.effects import Model
from manus.plants.errors import ManusError
from manus.plants.stepper import Controller, RefSample

NAMES = ("impedance", "slotine-li", "slotine-li-composite")
COMPOSITE_KNOBS = ("bandwidth", "weight", "forgetting")


def make_estimator(name: str, dt: float, model: Model, **knobs) -> Estimator:
    """The estimator called `name` (`manus.estimators.NAMES`) for a controller of `model`; a model-based
    one (`*_model`) predicts with that model, and the controller hands it its estimates."""
    if name.endswith("_model"):
        knobs.setdefault("model", model)
    return estimators.make(name, dt, n_joints=model.n_joints, **knobs)


def make_controller(
    name: str, model: Model, dt: float, estimator: Estimator | str | None = None, **gains
) -> Controller:
    """The controller `name` (one of `NAMES`) for `model` at control period `dt` [s]."""
    if name not in NAMES:
        raise ManusError(f"unknown controller {name!r}: expected one of {', '.join(NAMES)}")
    if not isinstance(model, Model):
        raise ManusError(f"make_controller needs a manus.plants.effects.Model, not {type(model).__name__}")
    if isinstance(estimator, str):
        estimator = make_estimator(estimator, dt, model)
    if name == "impedance":
        unknown = sorted(set(gains) - {"stiffness", "damping", "limit"})
        if unknown:
            raise ManusError(f"impedance: unknown gain(s) {', '.join(unknown)} (expected stiffness, damping, limit)")
        if estimator is not None and abs(estimator.dt - dt) > 1e-12:
            raise ManusError(f"the velocity estimator runs at dt = {estimator.dt:g} s but the controller at {dt:g} s")
        for k in ("stiffness", "damping"):
            if k in gains and not np.all(np.isfinite(gains[k]) & (np.asarray(gains[k], float) > 0)):
                raise ManusError(
                    f"impedance: {k} must be positive definite (every entry finite and > 0), got {gains[k]}"
                )
        return Impedance(n_joints=model.n_joints, estimator=estimator, **gains)
    knobs = {k: gains.pop(k) for k in COMPOSITE_KNOBS if k in gains}
    if knobs and name != "slotine-li-composite":
        raise ManusError(f"{name}: {', '.join(knobs)} belong to slotine-li-composite")
    composite = Composite(**knobs) if name == "slotine-li-composite" else None
    import inspect

    settings = [
        k for k, p in inspect.signature(SlotineLi).parameters.items() if p.kind is p.KEYWORD_ONLY and k != "composite"
    ]
    unknown = sorted(set(gains) - set(settings))
    if unknown:
        raise ManusError(f"{name} has no setting {', '.join(unknown)} (its settings: {', '.join(settings)})")
    return SlotineLi(model, dt, estimator, composite=composite, **gains)


class Replay(Controller):
    """Open loop: the command `torque[k]` at tick k (the last row after the end), whatever is
    measured."""

    torque: Array  # (T, n)

    def init(self, q0):
        return jnp.zeros((), jnp.int32)

    def step(self, state, q, ref):
        return state + 1, self.torque[jnp.minimum(state, self.torque.shape[0] - 1)]


class PPD(Controller):
    """The EMPS rig's loop: force = gtau (kp kv (q_ref − q) − kv v̂), v̂ the first difference of
    the two-sample mean 0.5 (q_k + q_{k−1}) (EMPS README)."""

    kp: float
    kv: float
    gtau: float
    dt: float

    def init(self, q0):
        q0 = jnp.asarray(q0, float)
        return q0, q0  # q_{k-1}, mean_{k-1}

    def step(self, state, q, ref):
        q_prev, mean_prev = state
        mean = 0.5 * (q + q_prev)
        v = (mean - mean_prev) / self.dt
        return (q, mean), self.gtau * (self.kp * self.kv * (ref.q - q) - self.kv * v)


class LockedSpring(Controller):
    """The thesis's locked-joint test (§3.5, eq. 3.5): a virtual spring K (q_d,j − q_j) on the
    joint j that `spring_on` (one-hot) picks, and a stiff servo holding the locked coordinate
    c·q at c·q_d. (Arrays, not indices: the tests share one compilation.)"""

    spring_on: Array  # e_j (n,)
    lock: Array  # c (n,)
    stiffness: float = 10.0  # N·m/rad, eq. 3.5
    lock_stiffness: float = 1000.0
    lock_damping: float = 5.0
    estimator: Estimator = FilteredFirstDifference()

    def init(self, q0):
        return self.estimator.init(q0)

    def step(self, state, q, ref: RefSample):
        state, est = self.estimator.step(state, q)
        spring = self.stiffness * self.spring_on * (ref.q - q)
        phi = jnp.dot(self.lock, q - ref.q)
        return state, spring - (self.lock_stiffness * phi + self.lock_damping * jnp.dot(self.lock, est.qd)) * self.lock


def compiled_tick(
    info,
    controller: str,
    estimator: str,
    model_spec: str,
    structure: str | None,
    reference: str,
    limits=None,
    robot: str | None = None,
):
    """The hardware loop's tick (`manus.plants.hardware.CompiledTick`) of `controller` +
    `estimator` following `reference`, for the device described by `info` (its joints, rate,
    encoder and torque limit), within the rig's `limits` (`manus.plants.limits.Limits`; default:
    the thesis arm's), warmed up. `structure`: manus2 or axis (default: manus2 for a 2-joint
    device); `robot`: a URDF instead, adapted in pseudo-inertia coordinates."""
    from manus.plants import Model, structure_named
    from manus.plants.hardware import CompiledTick
    from manus.plants.limits import Limits
    from manus.plants.references import CENTRE, reference_named

    n = info.n_joints
    if robot is not None:
        from manus.plants.serial import Serial

        chain = Serial.from_urdf(robot)
        if chain.n_joints != n:
            raise ManusError(
                f"the device has {n} joint(s); the robot {robot} has {chain.n_joints} ({', '.join(chain.joint_names)})"
            )
        shape, structure = chain.pseudo(), "urdf"
    else:
        structure = structure or ("manus2" if n == 2 else "axis")
        if structure == "manus2" and n != 2:
            raise ManusError(f"the device has {n} joint(s); manus2 has 2 (use --structure axis)")
        shape = structure_named(structure, n)
    dt = 1.0 / info.rate_hz
    model = Model(shape, model_spec)
    limits = limits or Limits()
    limit = min(limits.torque, info.torque_limit)
    gains = {} if controller == "impedance" else {"limit": limit}
    c = make_controller(controller, model, dt, estimator=estimator, **gains)
    arm = structure == "manus2"
    try:
        ref = reference_named(reference, np.array(CENTRE) if arm else np.zeros(n), arm)
    except ManusError as e:
        raise ManusError(f"{e} (try --reference multisine)") from None
    tick = CompiledTick(c, ref, dt, info.counts_per_rev, n, limits, info.torque_limit)
    tick.warm_up()
    return tick
