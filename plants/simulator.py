"""The JAX simulator: a plant backend with the thesis's actuator and sensor chain.

One control period (1 kHz by default) of `Simulator.step`:

1. the command passes the actuator chain (thesis §2.2–2.5, §3.2): 12-bit ±10 V D/A,
   0.6 A/V amplifier, K_T = 3.7 N·m/A; the D/A both quantizes and saturates (±22.2 N·m);
2. it enters a delay line (the `delay` effect: the amplifier's 1 ms) and is held (zero-order
   hold) over the period;
3. the continuous dynamics are sub-stepped (`substeps` per period) with a Moreau-type time
   stepping scheme: Störmer–Verlet (second order) for the smooth torques, and the set-valued friction
   (coulomb, stribeck, asymmetry) solved implicitly each sub-step, so a joint at rest stays
   exactly at rest while the other torques stay below its static friction, and breaks away when
   they exceed it (no creep from a smoothed sign);
4. the encoder reports the position quantized to its grid (131072 counts/rev).

With `compliance` in the truth model, each joint is a motor driving its link through a shaft
spring (thesis Fig. 4-16); the encoder and the friction sit on the motor, inertia coupling and
gravity on the link.

Everything is pure: `reset`/`step` jit, vmap and scan.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import Array

from plants.effects import Compliance, Delay, Model
from plants.errors import ModelError
from plants.stepper import Plant
from plants.structures import Manus2

TINY_SPEED = 1e-12  # evaluates friction levels "at rest" on the right side of the sign


class Actuator(eqx.Module):
    """D/A converter, current amplifier and motor (thesis §2.2.1, §3.2, §2.5)."""

    dac_bits: int = eqx.field(default=12, static=True)
    volts: float = 10.0  # ± full scale
    amps_per_volt: float = 0.6
    torque_constant: float = 3.7  # N·m/A

    @property
    def torque_per_volt(self):
        return self.amps_per_volt * self.torque_constant

    @property
    def limit(self):
        """Largest torque magnitude the chain can deliver [N·m]."""
        return self.volts * self.torque_per_volt

    def __call__(self, tau: Array) -> Array:
        """The torque the motor delivers for the command `tau` (quantized, saturated)."""
        lsb = 2 * self.volts / 2**self.dac_bits
        code = jnp.clip(jnp.round(tau / self.torque_per_volt / lsb), -(2 ** (self.dac_bits - 1)), 2 ** (self.dac_bits - 1) - 1)
        return code * lsb * self.torque_per_volt


class Encoder(eqx.Module):
    """An incremental encoder: reports positions on a grid of `step` [rad or m]."""

    step: float = 2 * math.pi / 131072  # thesis §2.6: 131072 counts/rev

    @classmethod
    def counts_per_rev(cls, counts: float) -> "Encoder":
        return cls(step=2 * math.pi / counts)

    def counts(self, q: Array) -> Array:
        return jnp.round(q / self.step)

    def __call__(self, q: Array) -> Array:
        return self.counts(q) * self.step


class SimState(NamedTuple):
    q: Array  # measured (motor-side) position (n,)
    qd: Array
    link_q: Array | None  # link side, with compliance only
    link_qd: Array | None
    commands: Array  # past commands, newest first (L, n)
    key: Array


def workspace_centre(model: Model) -> Array:
    """Thesis App. C: the centre of the workspace, q = (0.464, 2.409) rad; zeros for axes."""
    if isinstance(model.structure, Manus2):
        return jnp.array([0.464, 2.409])
    return jnp.zeros(model.n_joints)


class Simulator(Plant):
    """The plant simulated in JAX. `model` holds the truth effects, `params` their values."""

    model: Model
    params: dict
    rate_hz: float = eqx.field(default=1000.0, static=True)
    substeps: int = eqx.field(default=10, static=True)
    actuator: Actuator | None = Actuator()
    encoder: Encoder | None = Encoder()
    torque_noise: float = 0.0  # std of a white torque disturbance per control period [N·m]
    q0: Array | None = None  # initial position; default: workspace centre

    def __init__(self, model: Model, params: dict | None = None, *, rate_hz=1000.0, substeps=10,
                 actuator: Actuator | None = Actuator(), encoder: Encoder | None = Encoder(),
                 torque_noise=0.0, q0=None):
        if not model.has("rigid"):
            raise ModelError("a simulated plant needs the 'rigid' effect (its inertia)")
        self.model = model
        defaults = model.defaults()
        unknown = sorted(set(params or {}) - set(defaults))
        if unknown:
            raise ModelError(f"unknown parameter(s) {', '.join(unknown)} for effects {model.spec}")
        self.params = {k: jnp.asarray((params or {}).get(k, v), float) for k, v in defaults.items()}
        self.rate_hz = float(rate_hz)
        self.substeps = int(substeps)
        self.actuator = actuator
        self.encoder = encoder
        self.torque_noise = torque_noise
        self.q0 = workspace_centre(model) if q0 is None else jnp.asarray(q0, float)

    # -- configuration ---------------------------------------------------------------------
    @property
    def dt(self) -> float:
        """Control period [s]."""
        return 1.0 / self.rate_hz

    @property
    def delay(self) -> float:
        e = self.model.get("delay")
        return e.seconds if isinstance(e, Delay) else 0.0

    @property
    def compliance(self) -> Compliance | None:
        e = self.model.get("compliance")
        return e if isinstance(e, Compliance) else None

    def _lags(self) -> tuple[int, ...]:
        """For each sub-step, how many periods old the command acting on it is."""
        m = round(self.delay * self.rate_hz * self.substeps)  # delay in sub-steps
        return tuple(max(0, -((j - m) // self.substeps)) for j in range(self.substeps))

    # -- plant interface -------------------------------------------------------------------
    def reset(self, key: Array | None = None, q0: Array | None = None, qd0: Array | None = None):
        key = jax.random.PRNGKey(0) if key is None else key
        n = self.model.n_joints
        q = self.q0 if q0 is None else jnp.asarray(q0, float)
        q = jnp.broadcast_to(q, (n,)).astype(float)
        qd = jnp.zeros(n) if qd0 is None else jnp.broadcast_to(jnp.asarray(qd0, float), (n,))
        link = (q, qd) if self.compliance is not None else (None, None)
        commands = jnp.zeros((max(self._lags()) + 1, n))
        state = SimState(q, qd, link[0], link[1], commands, key)
        return state, self.measure(state)

    def measure(self, state: SimState) -> Array:
        return state.q if self.encoder is None else self.encoder(state.q)

    def truth(self, state: SimState) -> tuple[Array, Array]:
        """True position and velocity of the measured coordinate."""
        return state.q, state.qd

    def step(self, state: SimState, command: Array):
        u = command if self.actuator is None else self.actuator(command)
        commands = jnp.concatenate([u[None], state.commands[:-1]])
        taus = commands[jnp.array(self._lags())]  # (substeps, n), zero-order hold + delay
        key, sub = jax.random.split(state.key)
        if self.torque_noise:
            taus = taus + self.torque_noise * jax.random.normal(sub, u.shape)
        h = self.dt / self.substeps
        if self.compliance is None:
            def body(carry, tau):
                return self._substep_rigid(*carry, tau, h), None
            (q, qd), _ = jax.lax.scan(body, (state.q, state.qd), taus)
            new = SimState(q, qd, None, None, commands, key)
        else:
            def body(carry, tau):
                return self._substep_compliant(*carry, tau, h), None
            (q, qd, lq, lqd), _ = jax.lax.scan(body, (state.q, state.qd, state.link_q, state.link_qd), taus)
            new = SimState(q, qd, lq, lqd, commands, key)
        return new, self.measure(new)

    # -- dynamics ---------------------------------------------------------------------------
    def _friction_bounds(self, q, qd, side=None):
        """Friction levels (lo, hi) ≥ 0: f ∈ [−lo, hi], f = hi when sliding forward."""
        spd = jnp.maximum(jnp.abs(qd), TINY_SPEED)
        z = jnp.zeros_like(qd)
        hi = self.model.torque(q, spd, z, self.params, kinds=("friction",), side=side)
        lo = -self.model.torque(q, -spd, z, self.params, kinds=("friction",), side=side)
        return jnp.maximum(lo, 0.0), jnp.maximum(hi, 0.0)

    # Each sub-step is Störmer–Verlet (positions at the midpoint) with the velocity-dependent
    # torques taken at a predicted midpoint velocity: second order, and for springs exactly
    # conservative (stable for ωh < 2, right for a lightly damped shaft mode). Friction is the
    # implicit Moreau step at the midpoint; the position update uses the mean of the old and
    # new velocities, so a joint at rest before and after the step does not move at all.
    def _accel_rigid(self, q, qd, tau):
        s, p = self.model.structure, self.params
        r = tau - s.coriolis(q, qd, p) @ qd - self.model.torque(q, qd, jnp.zeros_like(qd), p, kinds=("load",))
        return s.solve(s.inertia(q, p), r)

    def _substep_rigid(self, q, qd, tau, h):
        s, p = self.model.structure, self.params
        qm = q + 0.5 * h * qd
        vm = qd + 0.5 * h * self._accel_rigid(q, qd, tau)
        vstar = qd + h * self._accel_rigid(qm, vm, tau)
        H = s.inertia(qm, p)
        lo, hi = self._friction_bounds(qm, qd)
        f = s.friction_solve(H, vstar, lo, hi, h)
        # a joint whose friction is strictly inside its bounds is stuck: exactly at rest
        v = jnp.where((f > -lo) & (f < hi), 0.0, vstar - h * s.solve(H, f))
        return q + 0.5 * h * (qd + v), v

    def _accel_compliant(self, th, thd, q, qd, tau):
        s, p, c = self.model.structure, self.params, self.compliance
        H = s.inertia(q, p)
        jm = c.motor_fraction * jnp.diagonal(H)  # motor rotor inertia; the link has the rest
        k, b = c.shaft(jnp.diagonal(H))
        shaft = k * (th - q) + b * (thd - qd)
        z = jnp.zeros_like(qd)
        am = (tau - shaft - self.model.torque(th, thd, z, p, kinds=("load",), side="motor")) / jm
        rl = shaft - s.coriolis(q, qd, p) @ qd - self.model.torque(q, qd, z, p, kinds=("load",), side="link")
        return am, s.solve(H - jnp.diag(jm), rl), jm

    def _substep_compliant(self, th, thd, q, qd, tau, h):
        am, al, _ = self._accel_compliant(th, thd, q, qd, tau)
        thm, qm = th + 0.5 * h * thd, q + 0.5 * h * qd
        am, al, jm = self._accel_compliant(thm, thd + 0.5 * h * am, qm, qd + 0.5 * h * al, tau)
        vstar = thd + h * am
        # the motor's inertia is diagonal: the implicit friction step is a clip per joint
        lo, hi = self._friction_bounds(thm, thd, side="motor")
        f = jnp.clip(jm * vstar / h, -lo, hi)
        v = jnp.where((f > -lo) & (f < hi), 0.0, vstar - h * f / jm)
        w = qd + h * al
        return th + 0.5 * h * (thd + v), v, q + 0.5 * h * (qd + w), w
