"""The stepper interfaces shared by plants, estimators and controllers (docs/architecture.md).

A stepper is an `equinox.Module` holding configuration only. Its state is an explicit pytree:
`init(...) -> state` and `step(state, inputs) -> (state, outputs)` are pure, so the same object
runs inside `jax.lax.scan` (simulation, recorded arrays) and, jitted once, in a Python
real-time loop.
"""

from __future__ import annotations

import abc
from typing import Any, NamedTuple

import equinox as eqx
from jax import Array


class RefSample(NamedTuple):
    """A reference at one instant: desired position, velocity, acceleration, each (n,)."""

    q: Array
    qd: Array
    qdd: Array


class Reference(eqx.Module):
    """A desired trajectory: `reference(t)` -> RefSample, jit-able in t."""

    @abc.abstractmethod
    def __call__(self, t) -> RefSample: ...


class Controller(eqx.Module):
    """Measured positions and a reference in, joint torque commands out."""

    @abc.abstractmethod
    def init(self, q0: Array) -> Any:
        """State before the first tick, given the first measured position."""

    @abc.abstractmethod
    def step(self, state: Any, q: Array, ref: RefSample) -> tuple[Any, Array]:
        """One control tick: the measured position q (n,) -> (state, torque command (n,))."""


class Plant(eqx.Module):
    """A world that takes torque commands and returns measured positions, one tick at a time.

    Backends: the JAX simulator (`manus.plants.simulator.Simulator`) and the hardware loop.
    """

    @abc.abstractmethod
    def reset(self, key: Array | None = None) -> tuple[Any, Array]:
        """-> (state, first measured position (n,))."""

    @abc.abstractmethod
    def step(self, state: Any, command: Array) -> tuple[Any, Array]:
        """Hold `command` (n,) for one control period -> (state, next measured position)."""
