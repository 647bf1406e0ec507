"""Reading a URDF file (numpy): its links and joints, and each link's ten standard inertial
parameters in its own frame (`manus.plants.serial` builds a chain from them)."""

from __future__ import annotations

import math
import pathlib
import xml.etree.ElementTree as ET
from typing import NamedTuple, cast

import numpy as np

from manus.plants.errors import ModelError


def _rpy(rpy) -> np.ndarray:
    """The URDF rotation Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _floats(element, attribute: str, default: str) -> np.ndarray:
    text = default if element is None else element.get(attribute, default)
    return np.array([float(v) for v in text.split()])


def _origin(element) -> tuple[np.ndarray, np.ndarray]:
    """(R, p) of an `<origin>` child: the child frame's rotation and position in the parent's."""
    origin = element.find("origin")
    return _rpy(_floats(origin, "rpy", "0 0 0")), _floats(origin, "xyz", "0 0 0")


def _skew(v) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def link_inertial(link) -> np.ndarray:
    """A link's ten standard parameters in its own frame (zeros without `<inertial>`)."""
    inertial = link.find("inertial")
    if inertial is None:
        return np.zeros(10)
    R, c = _origin(inertial)
    m = float(inertial.find("mass").get("value"))
    e = inertial.find("inertia")
    get = lambda k: float(e.get(k, "0"))
    I_c = np.array(
        [
            [get("ixx"), get("ixy"), get("ixz")],
            [get("ixy"), get("iyy"), get("iyz")],
            [get("ixz"), get("iyz"), get("izz")],
        ]
    )
    why = _unphysical(m, c, I_c)
    if why:
        raise ModelError(f"link {link.get('name')}: {why}")
    return _ten(m, m * c, R @ I_c @ R.T + m * _skew(c).T @ _skew(c))


def _unphysical(m: float, c: np.ndarray, I_c: np.ndarray) -> str:
    """What no rigid body can have ('' when nothing): a mass that is negative or not finite, a
    centre of mass or inertia that is not finite, a rotational inertia about the centre of mass
    that is not positive semi-definite. (The triangle inequality of the principal moments is not
    asked: published URDFs break it on placeholder links, 54 of 2152 links of example-robot-data's.)"""
    if not (math.isfinite(m) and m >= 0):
        return f"mass {m!r} kg (a mass is a non-negative finite number)"
    if not (np.all(np.isfinite(c)) and np.all(np.isfinite(I_c))):
        return "a centre of mass or an inertia that is not finite"
    moments = np.linalg.eigvalsh(I_c)
    tol = 1e-3 * float(np.abs(moments).max()) + 1e-12  # (rounding in a file written to a few digits)
    if moments[0] < -tol:
        return f"an inertia with a negative principal moment ({moments[0]:.4g} kg m²)"
    return ""


def _ten(m: float, h: np.ndarray, I_o: np.ndarray) -> np.ndarray:
    return np.array([m, *h, I_o[0, 0], I_o[0, 1], I_o[0, 2], I_o[1, 1], I_o[1, 2], I_o[2, 2]])


def moved(theta: np.ndarray, R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Ten parameters given in a frame placed at (R, p), expressed in the outer frame instead."""
    m, h = theta[0], theta[1:4]
    Ixx, Ixy, Ixz, Iyy, Iyz, Izz = theta[4:]
    I_o = R @ np.array([[Ixx, Ixy, Ixz], [Ixy, Iyy, Iyz], [Ixz, Iyz, Izz]]) @ R.T
    Rh = R @ h
    # parallel axis about the new origin: I + S(p)ᵀS(Rh) + S(Rh)ᵀS(p) + m S(p)ᵀS(p) (S: cross product)
    I_new = I_o + _skew(p).T @ _skew(Rh) + _skew(Rh).T @ _skew(p) + m * _skew(p).T @ _skew(p)
    return _ten(m, Rh + m * p, I_new)


class Joint(NamedTuple):
    name: str
    kind: str
    parent: str
    child: str
    R: np.ndarray
    p: np.ndarray
    axis: np.ndarray
    armature: float
    mimic: bool
    damping: float = 0.0  # <dynamics damping> [N·m·s/rad or N·s/m]
    friction: float = 0.0  # <dynamics friction> [N·m or N]


def read(path) -> tuple[dict, dict]:
    """The URDF's links (name → element) and joints (name → `_Joint`)."""
    path = pathlib.Path(path)
    if not path.is_file():
        raise ModelError(f"{path}: no such URDF file")
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as e:
        raise ModelError(f"{path}: not a readable URDF ({e})") from e
    if root.tag != "robot":
        raise ModelError(f"{path}: not a URDF (root element <{root.tag}>, expected <robot>)")
    links = {link.get("name"): link for link in root.findall("link")}
    joints = {}
    for j in root.findall("joint"):
        R, p = _origin(j)
        axis = _floats(j.find("axis"), "xyz", "1 0 0")
        dynamics = j.find("dynamics")
        # a malformed file's missing attribute (None) or element (AttributeError) is refused by Serial.from_urdf
        parent = j.find("parent").get("link")  # pyright: ignore[reportOptionalMemberAccess]
        child = j.find("child").get("link")  # pyright: ignore[reportOptionalMemberAccess]
        for key in ("armature", "damping", "friction"):
            value = float(dynamics.get(key, "0")) if dynamics is not None else 0.0
            if not (math.isfinite(value) and value >= 0):
                raise ModelError(
                    f"{path}: joint {j.get('name')}: <dynamics {key}={value!r}> (a non-negative finite number)"
                )
        joints[j.get("name")] = Joint(
            cast(str, j.get("name")),
            cast(str, j.get("type")),
            cast(str, parent),
            cast(str, child),
            R,
            p,
            axis / np.linalg.norm(axis),
            float(dynamics.get("armature", "0")) if dynamics is not None else 0.0,
            j.find("mimic") is not None,
            *(
                (float(dynamics.get("damping", "0")), float(dynamics.get("friction", "0")))
                if dynamics is not None
                else (0.0, 0.0)
            ),
        )
    return links, joints


class TransmissionElement(NamedTuple):
    """A `<transmission>` element: its type, its joints and its actuators, each with its
    `mechanicalReduction` (1 when not given)."""

    name: str
    kind: str
    joints: list[tuple[str, float]]
    actuators: list[tuple[str, float]]


def _reduction(element) -> float:
    r = element.find("mechanicalReduction")
    return 1.0 if r is None or r.text is None else float(r.text)


def transmissions(path) -> list[TransmissionElement]:
    """The URDF's `<transmission>` elements (ROS's format; the older one with the type as an attribute
    and the reduction beside the actuator is read too)."""
    root = ET.parse(pathlib.Path(path)).getroot()
    out = []
    for t in root.findall("transmission"):
        kind = t.findtext("type") or t.get("type") or ""
        outer = _reduction(t)  # the older format's, one for the transmission
        out.append(
            TransmissionElement(
                t.get("name", ""),
                kind.strip(),
                [(cast(str, j.get("name")), _reduction(j)) for j in t.findall("joint")],
                [(cast(str, a.get("name")), _reduction(a) * outer) for a in t.findall("actuator")],
            )
        )
    return out
