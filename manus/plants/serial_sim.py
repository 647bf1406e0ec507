"""Simulated recordings of a serial robot: an excitation, a controller that tracks it, a recording.

The simulator itself is `manus.plants.simulator.Simulator`: a `Serial` chain offers its joint-tuple
form (H(q) by the RNEA, dense, with the coupled stick-slip step of `manus.plants.serial_friction`),
so friction, delay and the other effects act on each joint's own coordinate as for every structure.
What a robot arm needs beyond that is a controller that holds it up against gravity while it
follows an exciting motion:

- `Feedforward`: τ = τ_rigid(q_d, q̇_d, q̈_d; θ̂) + K (q_d − q) + B (q̇_d − v̂), the chain's rigid
  torque along the reference (nominal parameters θ̂, the URDF's by default) plus a PD on the
  tracking error, v̂ a first difference low-passed at `velocity_hz`;
- `Fourier`: an excitation (a finite Fourier series per joint, as robot identification uses);
- `record`: the closed loop run for some seconds, as a `structure: urdf` recording (its `robot` the
  chain's URDF file).

Tested (tests/plants/test_serial_sim.py): the simulated Panda against RK4 on pinocchio's
articulated-body algorithm (5e-9 rad over 0.2 s at 10 sub-steps), joints held by Coulomb friction
exactly at rest, a pushed joint breaking away while the others stay stuck.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.typing import ArrayLike

from manus.plants.closed_loop import simulate
from manus.plants.recording import from_trajectory
from manus.plants.references import PositionReference
from manus.plants.stepper import Controller, RefSample
from manus.plants.structures import Structure


class Feedforward(Controller):
    """Computed-torque feedforward along the reference plus a PD on the error (see the module docstring)."""

    structure: Structure  # a Serial (or its base form)
    params: dict  # its rigid parameters (nominal)
    stiffness: Array  # K (n,) [N·m/rad]
    damping: Array  # B (n,) [N·m·s/rad]
    dt: float = eqx.field(static=True)
    velocity_hz: float = eqx.field(default=100.0, static=True)

    def __init__(
        self,
        structure,
        dt: float,
        params: dict | None = None,
        stiffness: ArrayLike = 400.0,
        damping: ArrayLike = 20.0,
        velocity_hz: float = 100.0,
    ):
        n = structure.n_joints
        self.structure = structure
        names, values = structure.rigid_names, structure.rigid_defaults
        self.params = {k: jnp.asarray((params or {}).get(k, v), float) for k, v in zip(names, values, strict=True)}
        self.stiffness = jnp.broadcast_to(jnp.asarray(stiffness, float), (n,))
        self.damping = jnp.broadcast_to(jnp.asarray(damping, float), (n,))
        self.dt = float(dt)
        self.velocity_hz = float(velocity_hz)

    def init(self, q0):
        q0 = jnp.asarray(q0, float)
        return q0, jnp.zeros_like(q0)

    def step(self, state, q, ref: RefSample):
        q_prev, v = state
        a = 1.0 - math.exp(-2 * math.pi * self.velocity_hz * self.dt)
        v = v + a * ((q - q_prev) / self.dt - v)
        tau = (
            self.structure.rigid_torque(ref.q, ref.qd, ref.qdd, self.params)
            + self.stiffness * (ref.q - q)
            + self.damping * (ref.qd - v)
        )
        return (q, v), tau


def record(
    simulator,
    reference,
    seconds: float,
    controller: Controller | None = None,
    key=None,
    counts_per_rev: float | None = None,
    meta: dict | None = None,
):
    """The closed loop of `simulator` (a serial chain's) tracking `reference` for `seconds`, as a
    recording (`structure: urdf`, true velocities, the reference in `qref*`). `controller`:
    default `Feedforward` on the URDF's parameters."""
    structure = simulator.model.structure
    controller = controller or Feedforward(structure, simulator.dt)
    traj = simulate(simulator, controller, reference, seconds, key=key)
    if counts_per_rev is None and simulator.encoder is not None:
        counts_per_rev = 2 * np.pi / float(simulator.encoder.step)
    return from_trajectory(
        traj, simulator.rate_hz, structure, counts_per_rev, {"truth": simulator.model.spec, **(meta or {})}
    )


class Fourier(PositionReference):
    """A finite Fourier series per joint (Swevers et al. 1997, the usual robot excitation):
    q_i(t) = c_i + Σ_k a_ik (sin(2π k f_i t + φ_ik) − sin φ_ik), k = 1..`harmonics`, with each
    joint's fundamental f_i a little apart from the others' (`f0` [Hz] times 1, 1.07, 1.14, ...: no
    shared lines), amplitudes ∝ k^−`decay` summing to `amplitude` [rad or m] per joint and random
    phases (`seed`); faded in over `ramp` s from rest at `centre`. A decay above 1 makes the slow
    harmonics carry the velocity, so that each joint reverses (and may stick) about twice per
    fundamental period only."""

    centre: Array
    freqs: Array  # (n, k) Hz
    amps: Array  # (n, k)
    phases: Array  # (n, k)
    ramp: float = 0.5

    def __init__(self, centre, amplitude=0.5, f0=0.2, harmonics=5, decay=1.5, seed=0, ramp=0.5):
        centre = np.atleast_1d(np.asarray(centre, float))
        n = centre.size
        k = np.arange(1, harmonics + 1)
        freqs = np.outer(f0 * (1 + 0.07 * np.arange(n)), k)
        amps = (
            np.broadcast_to(np.asarray(amplitude, float).reshape(-1, 1) * np.ones((n, 1)), (n, 1))
            * (k**-decay)
            / np.sum(k**-decay)
        )
        self.centre = jnp.asarray(centre)
        self.freqs = jnp.asarray(freqs)
        self.amps = jnp.asarray(amps)
        self.phases = jnp.asarray(np.random.default_rng(seed).uniform(0, 2 * np.pi, freqs.shape))
        self.ramp = float(ramp)

    def position(self, t):
        x = jnp.clip(t / self.ramp, 0.0, 1.0) if self.ramp > 0 else 1.0
        fade = x * x * x * (10 - 15 * x + 6 * x * x)  # smoothstep: zero slope and curvature at 0
        wave = jnp.sum(self.amps * (jnp.sin(2 * jnp.pi * self.freqs * t + self.phases) - jnp.sin(self.phases)), axis=1)
        return self.centre + fade * wave
