"""The stepper interfaces shared by plants, estimators and controllers (docs/architecture.md).

A stepper is an `equinox.Module` holding configuration only. Its state is an explicit pytree:
`init(...) -> state` and `step(state, inputs) -> (state, outputs)` are pure, so the same object
runs inside `jax.lax.scan` (simulation, recorded arrays) and, jitted once, in a Python
real-time loop.
"""

import abc
from typing import TYPE_CHECKING, Any, NamedTuple

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

    def velocity(self, state: Any) -> Array | None:
        """The velocity estimate (n,) the controller keeps in `state`, for logs; None when it keeps none."""
        return None

    def stopped(self, state: Any) -> Array | bool:
        """Whether the controller has stopped itself for good in `state` (a latched stop: zero
        torque from then on); False for a controller that never does."""
        return False


class Plant(eqx.Module):
    """A world that takes torque commands and returns measured positions, one tick at a time.

    Backends: the JAX simulator (`manus.plants.simulator.Simulator`), a simulated plant with a
    disturbance (`manus.plants.disturbed.Disturbed`) and the rig itself
    (`manus.plants.hardware.HardwarePlant`, imperative: outside `jit`). Closed loops
    (`manus.plants.closed_loop`, `manus.adaptive.slotine_li`) use exactly what is declared here.
    """

    if TYPE_CHECKING:  # a type checker reads an AbstractVar as a dataclass field, which a property cannot override

        @property
        def dt(self) -> float:
            """The control period [s]."""
            ...

        @property
        def params(self) -> dict:
            """The true values of the plant's parameters by name (a simulated plant's truth); {} when
            they are unknown (the rig)."""
            ...
    else:  # (this module's annotations are not strings: equinox needs its AbstractVar evaluated)
        dt: eqx.AbstractVar[float]
        params: eqx.AbstractVar[dict]

    @abc.abstractmethod
    def reset(self, key: Array | None = None, q0: Array | None = None, qd0: Array | None = None) -> tuple[Any, Array]:
        """-> (state, first measured position (n,)), starting at rest at q0 (or where the plant
        starts by default) with velocity qd0 (default zero), with the noise key `key`."""

    @abc.abstractmethod
    def step(self, state: Any, command: Array) -> tuple[Any, Array]:
        """Hold `command` (n,) for one control period -> (state, next measured position)."""

    @abc.abstractmethod
    def truth(self, state: Any) -> tuple[Array, Array]:
        """The true position and velocity (n,) of the measured coordinate in `state`."""
