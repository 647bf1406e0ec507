"""The JAX simulator: a plant backend with the thesis's actuator and sensor chain.

One control period (1 kHz by default) of `Simulator.step`:

1. the command passes the actuator chain (thesis §2.2–2.5, §3.2): 12-bit ±10 V D/A,
   0.6 A/V amplifier, K_T = 3.7 N·m/A; the D/A both quantizes and saturates (±22.2 N·m);
2. it enters a delay line (the `delay` effect: the amplifier's 1 ms) and is held (zero-order
   hold) over the period, plus `torque_noise` times a white Gaussian draw per period and joint
   (`white_noise`: counter-based, the period's count under the reset's key);
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
import numpy as np
from jax import Array

from manus.plants.effects import Compliance, Delay, Model, is_dry, is_load
from manus.plants.errors import ModelError
from manus.plants.stepper import Plant
from manus.plants.structures import Diagonal, Joints, greater, joints

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
        code = jnp.clip(
            jnp.round(tau / self.torque_per_volt / lsb), -(2 ** (self.dac_bits - 1)), 2 ** (self.dac_bits - 1) - 1
        )
        return code * lsb * self.torque_per_volt


class Encoder(eqx.Module):
    """An incremental encoder: reports positions on a grid of `step` [rad or m]."""

    step: float = 2 * math.pi / 131072  # thesis §2.6: 131072 counts/rev

    @classmethod
    def counts_per_rev(cls, counts: float) -> Encoder:
        return cls(step=2 * math.pi / counts)

    def counts(self, q: Array) -> Array:
        return jnp.round(q / self.step)

    def __call__(self, q: Array) -> Array:
        return self.counts(q) * self.step


THESIS_ACTUATOR, THESIS_ENCODER = Actuator(), Encoder()  # the thesis's D/A, amplifier and motor; its encoder


class SimState(NamedTuple):
    q: Array  # measured (motor-side) position (n,)
    qd: Array
    link_q: Array | None  # link side, with compliance only
    link_qd: Array | None
    commands: Array  # past commands, newest first (L, n)
    key: Array
    tick: Array | None = None  # control periods since reset (uint32): the torque noise's counter


def workspace_centre(model: Model) -> Array:
    """Where a simulated run starts unless told otherwise: the structure's `workspace_centre`
    (MANUS-2: thesis App. C's q = (0.464, 2.409) rad; zeros elsewhere)."""
    return jnp.array(model.structure.workspace_centre, float)


def white_noise(key: Array, tick: Array, n: int) -> Array:
    """The torque noise's n standard normal draws (float32) for control period `tick` of the
    stream `key`: counter-based, so the draw of any period costs the same and needs no key
    carried from period to period.

    Threefry-2x32 (JAX's generator) of the counter (tick, block) under `key` gives 32 random bits
    per draw; their top 24, as the odd integer m in (−2²⁴, 2²⁴), give v = m / 2²⁴ in (−1, 1),
    uniform and symmetric, and z = √2 erf⁻¹(v) (as `jax.random.normal` does; float32, whose
    erf⁻¹ XLA vectorizes, unlike float64's). Tails stop at |z| ≈ 5.4 (probability 2⁻²⁴).
    Distinct ticks and blocks are distinct counters: independent draws (tested: mean, variance,
    autocorrelation and distribution against numpy's generator)."""
    from jax.extend.random import threefry_2x32

    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):  # a typed key: its raw pair
        key = jax.random.key_data(key)
    blocks = (n + 1) // 2  # one Threefry block gives two draws
    tick = jnp.asarray(tick, jnp.uint32)
    count = jnp.concatenate([jnp.broadcast_to(tick, (blocks,)), jnp.arange(blocks, dtype=jnp.uint32)])
    bits = threefry_2x32(key, count)[:n]
    odd = (jax.lax.shift_right_logical(bits, jnp.uint32(7)) | jnp.uint32(1)).astype(jnp.int32) - (1 << 24)
    v = odd.astype(jnp.float32) * jnp.float32(2.0**-24)
    return jnp.float32(math.sqrt(2.0)) * jax.lax.erf_inv(v)


class Simulator(Plant):
    """The plant simulated in JAX. `model` holds the truth effects, `params` their values."""

    model: Model
    params: dict
    rate_hz: float = eqx.field(default=1000.0, static=True)
    substeps: int = eqx.field(default=10, static=True)
    actuator: Actuator | None = THESIS_ACTUATOR
    encoder: Encoder | None = THESIS_ENCODER
    torque_noise: float = 0.0  # std of a white torque disturbance per control period [N·m]
    q0: Array | None = None  # initial position; default: workspace centre

    def __init__(
        self,
        model: Model,
        params: dict | None = None,
        *,
        rate_hz=1000.0,
        substeps=10,
        actuator: Actuator | None = THESIS_ACTUATOR,
        encoder: Encoder | None = THESIS_ENCODER,
        torque_noise=0.0,
        q0=None,
    ):
        if not model.has("rigid"):
            raise ModelError("a simulated plant needs the 'rigid' effect (its inertia)")
        self.model = model
        given = params or {}
        unknown = sorted(set(given) - set(model.names))
        if unknown:
            raise ModelError(f"unknown parameter(s) {', '.join(unknown)} for effects {model.spec}")
        # the defaults only where a parameter is not given (a model traced under jit has no numbers)
        defaults = model.defaults() if any(k not in given for k in model.names) else {}
        self.params = {k: jnp.asarray(given[k] if k in given else defaults[k], float) for k in model.names}
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
    def delays(self) -> np.ndarray:
        """Each joint's command delay [s], (n,)."""
        e = self.model.get("delay")
        return e.per_joint(self.model.n_joints) if isinstance(e, Delay) else np.zeros(self.model.n_joints)

    @property
    def delay(self) -> float:
        """The command delay [s] (the longest, when it differs between joints)."""
        return float(self.delays.max())

    @property
    def compliance(self) -> Compliance | None:
        e = self.model.get("compliance")
        return e if isinstance(e, Compliance) else None

    def _lags(self) -> np.ndarray:
        """For each sub-step and joint, how many periods old the command acting on it is, (substeps, n)."""
        m = np.round(self.delays * self.rate_hz * self.substeps).astype(int)  # delay in sub-steps
        j = np.arange(self.substeps)[:, None]
        return np.maximum(0, -((j - m[None, :]) // self.substeps))

    # -- plant interface -------------------------------------------------------------------
    def reset(self, key: Array | None = None, q0: Array | None = None, qd0: Array | None = None):
        key = jax.random.PRNGKey(0) if key is None else key
        n = self.model.n_joints
        q = self.q0 if q0 is None else jnp.asarray(q0, float)
        assert q is not None  # (set by __init__)
        q = jnp.broadcast_to(q, (n,)).astype(float)
        qd = jnp.zeros(n) if qd0 is None else jnp.broadcast_to(jnp.asarray(qd0, float), (n,))
        link = (q, qd) if self.compliance is not None else (None, None)
        commands = jnp.zeros((int(self._lags().max()) + 1, n))
        state = SimState(q, qd, link[0], link[1], commands, key, jnp.zeros((), jnp.uint32))
        return state, self.measure(state)

    def measure(self, state: SimState) -> Array:
        return state.q if self.encoder is None else self.encoder(state.q)

    def truth(self, state: SimState) -> tuple[Array, Array]:
        """True position and velocity of the measured coordinate."""
        return state.q, state.qd

    def step(self, state: SimState, command: Array):
        u = command if self.actuator is None else self.actuator(command)
        commands = jnp.concatenate([u[None], state.commands[:-1]])
        key = state.key
        held = commands  # zero-order hold + delay: sub-step j applies held[lag_j]
        assert state.tick is not None  # (set by reset)
        if self.torque_noise:  # the key stays; the period's counter picks the draw
            held = held + self.torque_noise * white_noise(key, state.tick, u.shape[0]).astype(held.dtype)
        tick = state.tick + jnp.uint32(1)
        h = self.dt / self.substeps
        n, s = self.model.n_joints, self.model.structure
        # The sub-steps run on per-joint scalars (see manus.plants.structures), stacked once per period;
        # sin and cos of the configuration once per period, then turned by each sub-step's move.
        # A joint's lags take at most two neighbouring values: a flag per sub-step and joint picks the older one.
        lags = self._lags()
        first, last = lags.min(axis=0), lags.max(axis=0)
        newer = tuple(held[first[i], i] for i in range(n))
        older = tuple(held[last[i], i] for i in range(n))
        late = lags > first

        def tau_of(is_late):
            return newer if is_late is None else tuple(jnp.where(is_late[i], older[i], newer[i]) for i in range(n))

        xs = late if late.any() else None
        q, qd = joints(state.q, n), joints(state.qd, n)
        if self.compliance is None:

            def rigid(carry, is_late):
                q, qd, pose, shift, bounds = carry
                return self._substep_rigid(q, qd, pose, shift, bounds, tau_of(is_late), h), None

            carry = (q, qd, s.pose(q), self._half_shift(qd, h), self._bounds_ahead(q, qd, h))
            (q, qd, *_), _ = jax.lax.scan(rigid, carry, xs, length=self.substeps)
            new = SimState(jnp.stack(q), jnp.stack(qd), None, None, commands, key, tick)
        else:
            assert state.link_q is not None and state.link_qd is not None  # (set by reset with compliance)
            lq, lqd = joints(state.link_q, n), joints(state.link_qd, n)

            def compliant(carry, is_late):
                th, thd, q, qd, pose, shift, bounds = carry
                return self._substep_compliant(th, thd, q, qd, pose, shift, bounds, tau_of(is_late), h), None

            carry = (q, qd, lq, lqd, s.pose(lq), self._half_shift(lqd, h), self._bounds_ahead(q, qd, h, "motor"))
            (q, qd, lq, lqd, *_), _ = jax.lax.scan(compliant, carry, xs, length=self.substeps)
            new = SimState(jnp.stack(q), jnp.stack(qd), jnp.stack(lq), jnp.stack(lqd), commands, key, tick)
        return new, self.measure(new)

    # -- dynamics, on per-joint scalars -----------------------------------------------------
    def _torque(self, q: Joints, qd: Joints, only, side=None) -> Joints:
        """The model's torques of the effects `only` accepts (`Model.torque` at q̈ = 0), per joint."""
        v = jnp.stack(qd)
        tau = self.model.torque(jnp.stack(q), v, jnp.zeros_like(v), self.params, only=only, side=side)
        return joints(tau, self.model.n_joints)

    def _friction_bounds(self, q: Joints, qd: Joints, side=None) -> tuple[Joints, Joints]:
        """Friction levels (lo, hi) ≥ 0: f ∈ [−lo, hi], f = hi when sliding forward."""
        spd = tuple(greater(jnp.abs(v), TINY_SPEED) for v in qd)
        hi = self._torque(q, spd, is_dry, side)
        lo = self._torque(q, tuple(-v for v in spd), is_dry, side)
        return tuple(greater(-x, 0.0) for x in lo), tuple(greater(x, 0.0) for x in hi)

    def _bounds_ahead(self, q: Joints, qd: Joints, h, side=None):
        """The friction bounds of the sub-step that starts at (q, q̇): at its midpoint q + h/2·q̇
        and speed |q̇|; () without friction."""
        if not any(e.dry and (side is None or e.side == side) for e in self.model.effects):
            return ()
        return self._friction_bounds(tuple(x + 0.5 * h * v for x, v in zip(q, qd, strict=True)), qd, side)

    def _implicit_friction(self, H, vstar: Joints, bounds, h) -> Joints:
        """The velocity after the implicit friction step with inertia H, v* − h H⁻¹ f, and
        exactly zero on a joint whose friction f is strictly inside its bounds (stuck)."""
        if not bounds:
            return vstar
        lo, hi = bounds
        f = H.friction(vstar, lo, hi, h)
        slide = H.solve(f)
        return tuple(
            jnp.where((fi > -l) & (fi < u), 0.0, v - h * a)
            for fi, l, u, v, a in zip(f, lo, hi, vstar, slide, strict=True)
        )

    def _half_shift(self, qd: Joints, h):
        """The structure's shift for a move by h/2·q̇."""
        return self.model.structure.shift(tuple(0.5 * h * v for v in qd))

    # Each sub-step is Störmer–Verlet (positions at the midpoint) with the velocity-dependent
    # torques taken at a predicted midpoint velocity: second order, and for springs exactly
    # conservative (stable for ωh < 2, right for a lightly damped shaft mode). Friction is the
    # implicit Moreau step at the midpoint; the position update uses the mean of the old and
    # new velocities, so a joint at rest before and after the step does not move at all.
    # `pose` (sin/cos of the configuration) moves by h/2·q̇ to the midpoint and by h/2·v from
    # there; `shift` carries the second half-move, which is also the next sub-step's first.
    # The friction bounds depend only on where a sub-step starts, so the previous one computes
    # them: as a loop output XLA evaluates them once, not again inside each of their consumers.
    def _accel_rigid(self, q, qd, pose, tau):
        s, p = self.model.structure, self.params
        r = tuple(t - b - l for t, b, l in zip(tau, s.bias(pose, qd, p), self._torque(q, qd, is_load), strict=True))
        return s.mass(pose, p).solve(r)

    def _substep_rigid(self, q, qd, pose, shift, bounds, tau, h):
        s = self.model.structure
        qm = tuple(x + 0.5 * h * v for x, v in zip(q, qd, strict=True))
        pm = s.moved(pose, shift)
        vm = tuple(v + 0.5 * h * a for v, a in zip(qd, self._accel_rigid(q, qd, pose, tau), strict=True))
        vstar = tuple(v + h * a for v, a in zip(qd, self._accel_rigid(qm, vm, pm, tau), strict=True))
        v = self._implicit_friction(s.mass(pm, self.params), vstar, bounds, h)
        q = tuple(x + 0.5 * h * (a + b) for x, a, b in zip(q, qd, v, strict=True))
        shift = self._half_shift(v, h)
        return q, v, s.moved(pm, shift), shift, self._bounds_ahead(q, v, h)

    def _accel_compliant(self, th, thd, q, qd, pose, tau):
        s, p, c = self.model.structure, self.params, self.compliance
        assert c is not None  # (the compliant sub-step runs with compliance only)
        H = s.mass(pose, p)
        jm = tuple(c.motor_fraction * x for x in H.diagonal())  # motor rotor inertia; the link has the rest
        shaft = []
        for x, a, b, ad, bd in zip(H.diagonal(), th, q, thd, qd, strict=True):
            k, d = c.shaft(x)
            shaft.append(k * (a - b) + d * (ad - bd))
        motor = self._torque(th, thd, is_load, "motor")
        link = self._torque(q, qd, is_load, "link")
        am = tuple((t - x - m) / j for t, x, m, j in zip(tau, shaft, motor, jm, strict=True))
        rl = tuple(x - b - l for x, b, l in zip(shaft, s.bias(pose, qd, p), link, strict=True))
        return am, H.minus_diagonal(jm).solve(rl), jm

    def _substep_compliant(self, th, thd, q, qd, pose, shift, bounds, tau, h):
        s = self.model.structure
        am, al, _ = self._accel_compliant(th, thd, q, qd, pose, tau)
        thm = tuple(x + 0.5 * h * v for x, v in zip(th, thd, strict=True))
        qm = tuple(x + 0.5 * h * v for x, v in zip(q, qd, strict=True))
        pm = s.moved(pose, shift)
        am, al, jm = self._accel_compliant(
            thm,
            tuple(v + 0.5 * h * a for v, a in zip(thd, am, strict=True)),
            qm,
            tuple(v + 0.5 * h * a for v, a in zip(qd, al, strict=True)),
            pm,
            tau,
        )
        vstar = tuple(v + h * a for v, a in zip(thd, am, strict=True))
        # the motor's inertia is diagonal: the implicit friction step is a clip per joint
        v = self._implicit_friction(Diagonal(jm), vstar, bounds, h)
        th = tuple(x + 0.5 * h * (a + b) for x, a, b in zip(th, thd, v, strict=True))
        w = tuple(v + h * a for v, a in zip(qd, al, strict=True))
        shift = self._half_shift(w, h)
        return (
            th,
            v,
            tuple(x + 0.5 * h * (a + b) for x, a, b in zip(q, qd, w, strict=True)),
            w,
            s.moved(pm, shift),
            shift,
            self._bounds_ahead(th, v, h, "motor"),
        )
