"""The structures by name, as recordings (`# structure: NAME`) and the command line name them:
`manus2` (`manus.plants.structures.Manus2`), `axis` (`Axis`) and `urdf` (a serial chain read from
a URDF file, `manus.plants.serial.Serial`)."""

from __future__ import annotations

from manus.plants.errors import ModelError
from manus.plants.serial import Serial
from manus.plants.structures import Axis, Manus2, Structure


def structure_named(name: str, n_joints: int, robot=None) -> Structure:
    """The structure called `name` with `n_joints` joints: "manus2", "axis", or "urdf" (a serial
    chain read from the URDF file `robot`, `manus.plants.serial.Serial`; a URDF whose chain has
    another number of joints is refused with a `ModelError`)."""
    if name == "manus2":
        if n_joints != 2:
            raise ValueError(f"structure manus2 has 2 joints, not {n_joints}")
        return Manus2()
    if name == "axis":
        return Axis(n_joints=n_joints)
    if name == "urdf":
        if robot is None:
            raise ModelError(
                "structure urdf needs the robot's URDF file (a recording's '# robot: PATH', or --robot FILE.urdf)"
            )
        serial = Serial.from_urdf(robot)
        if serial.n_joints != n_joints:
            raise ModelError(
                f"{robot}: the URDF's chain has {serial.n_joints} joints ({', '.join(serial.joint_names)}), "
                f"not {n_joints}"
            )
        return serial
    raise ValueError(f"unknown structure {name!r}: expected 'manus2', 'axis' or 'urdf'")
