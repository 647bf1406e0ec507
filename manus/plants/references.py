"""Reference trajectories: the thesis's benign and complex ones (App. C), a multi-sine, a set-point
step, reaching moves, and a recorded reference.

A reference defines its position q(t) once; velocity and acceleration come from forward-mode
differentiation, so they are exact and cannot drift out of step with the position.
"""

from __future__ import annotations

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from manus.plants.errors import ManusError
from manus.plants.stepper import Reference, RefSample

CENTRE = (0.464, 2.409)  # thesis App. C: workspace centre of MANUS-2 [rad]


class PositionReference(Reference):
    """A reference given by its position; `__call__` adds exact derivatives."""

    @abc.abstractmethod
    def position(self, t) -> Array: ...

    def __call__(self, t) -> RefSample:
        t = jnp.asarray(t, float)
        d1 = lambda s: jax.jvp(self.position, (s,), (jnp.ones_like(s),))
        q, qd = d1(t)
        _, qdd = jax.jvp(lambda s: d1(s)[1], (t,), (jnp.ones_like(t),))
        return RefSample(q, qd, qdd)


class Hold(PositionReference):
    """Stay at `q`."""

    q: Array = eqx.field(converter=lambda x: jnp.asarray(x, float))

    def position(self, t):
        return self.q + 0 * t


class Step(PositionReference):
    """`start` until `at` seconds, then `end`: a set-point step (thesis §4.1: 5 mm at 2 s).
    Its velocity and acceleration are zero everywhere (the jump itself has no derivative)."""

    start: Array = eqx.field(converter=lambda x: jnp.asarray(x, float))
    end: Array = eqx.field(converter=lambda x: jnp.asarray(x, float))
    at: float = 2.0

    def position(self, t):
        return jnp.where(t >= self.at, self.end, self.start) + 0 * t


class Benign(PositionReference):
    """Thesis eqs. C.11–C.12: both joints 0.1 rad at 0.5 Hz, in antiphase."""

    centre: tuple = CENTRE

    def position(self, t):
        w = 0.1 * (1 - jnp.cos(jnp.pi * t))
        return jnp.stack([self.centre[0] - w, self.centre[1] + w])


class Complex(PositionReference):
    """Thesis eqs. C.13–C.14: joint 1 0.1 rad at 2 Hz, joint 2 0.2 rad at 1 Hz."""

    centre: tuple = CENTRE

    def position(self, t):
        return jnp.stack(
            [self.centre[0] - 0.1 * (1 - jnp.cos(4 * jnp.pi * t)), self.centre[1] + 0.2 * (1 - jnp.cos(2 * jnp.pi * t))]
        )


class MultiSine(PositionReference):
    """An excitation for identification: per joint a sum of sines with log-spaced frequencies
    in [f_min, f_max] Hz, amplitudes ∝ 1/f (flat velocity spectrum) summing to `amplitude`,
    random phases (`seed`) and different frequencies on each joint; faded in over `ramp` s so
    that it starts at `centre` at rest."""

    centre: Array
    freqs: Array  # (n, k) Hz
    amps: Array  # (n, k)
    phases: Array  # (n, k)
    ramp: float = 0.5

    def __init__(self, centre=CENTRE, amplitude=0.15, f_min=0.2, f_max=3.0, components=6, seed=0, ramp=0.5):
        centre = np.atleast_1d(np.asarray(centre, float))
        n = centre.size
        rng = np.random.default_rng(seed)
        base = np.geomspace(f_min, f_max, components)
        ratio = (f_max / f_min) ** (1 / (components - 1)) if components > 1 else 1.3
        freqs = np.stack([base * ratio ** (i / n) for i in range(n)])  # interleaved: no shared lines
        amps = amplitude * (1 / freqs) / (1 / freqs).sum(1, keepdims=True)
        self.centre = jnp.asarray(centre)
        self.freqs = jnp.asarray(freqs)
        self.amps = jnp.asarray(amps)
        self.phases = jnp.asarray(rng.uniform(0, 2 * np.pi, freqs.shape))
        self.ramp = float(ramp)

    def position(self, t):
        x = jnp.clip(t / self.ramp, 0.0, 1.0) if self.ramp > 0 else 1.0
        fade = x * x * x * (10 - 15 * x + 6 * x * x)  # smoothstep: zero slope and curvature at 0
        w = 2 * jnp.pi * self.freqs
        wave = jnp.sum(self.amps * (jnp.sin(w * t + self.phases) - jnp.sin(self.phases)), axis=1)
        return self.centre + fade * wave


class Reaching(PositionReference):
    """Smooth (quintic) moves between targets with rests: q(t) = q0 + Σ_m Δ_m s((t − t_m)/T_m)."""

    start: Array  # (n,)
    t0: Array  # (M,) move start times
    duration: Array  # (M,)
    delta: Array  # (M, n)

    def position(self, t):
        x = jnp.clip((t - self.t0) / self.duration, 0.0, 1.0)
        s = x * x * x * (10 - 15 * x + 6 * x * x)
        return self.start + s @ self.delta


class Sampled(PositionReference):
    """A recorded reference, linearly interpolated between its samples."""

    t: Array
    q: Array  # (T, n)

    def position(self, t):
        return jnp.stack([jnp.interp(t, self.t, self.q[:, i]) for i in range(self.q.shape[1])])


NAMES = ("benign", "complex", "hold", "multisine")
THESIS_ARM_ONLY = ("benign", "complex")  # the thesis's trajectories, about MANUS-2's workspace centre


def reference_named(name: str, centre, arm: bool = True, amplitude: float = 0.15, seed: int = 0) -> PositionReference:
    """The reference called `name` (one of `NAMES`) about `centre`: the thesis's benign or complex
    trajectory (the MANUS-2 arm's only: `arm`), holding `centre`, or a multi-sine of `amplitude`
    with phases from `seed`."""
    if name not in NAMES:
        raise ManusError(f"unknown reference {name!r}: one of {', '.join(NAMES)}")
    if name in THESIS_ARM_ONLY and not arm:
        raise ManusError(f"the {name} trajectory is the thesis's for the manus2 arm")
    return {
        "benign": Benign,
        "complex": Complex,
        "hold": lambda: Hold(centre),
        "multisine": lambda: MultiSine(centre, amplitude, seed=seed),
    }[name]()
