"""The world: physical effects, the JAX simulator, closed-loop simulation, recordings."""

from manus.plants.catalog import structure_named
from manus.plants.effects import VOCABULARY, Effect, Model, parse_effects
from manus.plants.errors import ManusError, ModelError, RecordingError
from manus.plants.serial import Serial, SerialBase, SerialPseudo
from manus.plants.simulator import Actuator, Encoder, Simulator
from manus.plants.stepper import Controller, Plant, Reference, RefSample
from manus.plants.structures import Axis, Manus2, Structure

__all__ = [
    "VOCABULARY",
    "Effect",
    "Model",
    "parse_effects",
    "ManusError",
    "ModelError",
    "RecordingError",
    "Actuator",
    "Encoder",
    "Simulator",
    "Controller",
    "Plant",
    "Reference",
    "RefSample",
    "Axis",
    "Manus2",
    "Serial",
    "SerialBase",
    "SerialPseudo",
    "Structure",
    "structure_named",
]
