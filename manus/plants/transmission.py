"""Transmissions: how the actuators turn with the joints, θ = N q (docs/effects.md, "Transmissions
and couplings").

A motor need not turn with one joint alone: a differential wrist turns two motors with two joints
(θ5 = q5 + q6, θ6 = q5 − q6), the elbow motor of an arm in absolute angles turns with the
difference of two of them (θ2 = q2 − q1), a gear multiplies (θ = r q). N is square (one actuator
per joint) and invertible. The motor-side effects (friction, cogging, offset: `Effect.side ==
"motor"`) act on the actuators: their torque τ_a is evaluated at (N q, N q̇, N q̈) and reaches the
joints by virtual work, τ = Nᵀ τ_a (`Transmission.acting`). `Model.torque` applies it, so the
simulator, the regressors, the fit and the diagnosis all see the same map. An identity N is no
transmission (`None`): every result is the same as without one.

The structure carries its transmission (`Structure.transmission`). Three sources state it; the
later replaces the earlier: a URDF's `<transmission>` elements (`of_urdf`), a recording's header
line `# transmission: ...` and the command line's `--transmission` (`parse`). A statement is one
item per actuator, separated by `;`:

- a combination of joints, in actuator order: `q1; q2 - q1` (joints `q1`..`qn` or a URDF's joint
  names; coefficients `0.5 q5`, `2*q3`, `-q1`);
- `mK = combination` for actuator K alone, the others turning with their own joint: `m5 = q5 + q6;
  m6 = q5 - q6`;
- or the matrix itself, `[[1, 0], [-1, 1]]`.
"""

from __future__ import annotations

import dataclasses
import json
import re
from typing import Any, NamedTuple, TypeVar

import jax.numpy as jnp
import numpy as np

from manus.plants.errors import ModelError

S = TypeVar("S", bound=Any)  # a structure (`manus.plants.structures.Structure`, which imports this module's type)


class Transmission(NamedTuple):
    """θ = N q, N (n, n) invertible and not the identity, by rows (hashable: a structure's static field)."""

    rows: tuple[tuple[float, ...], ...]

    @property
    def matrix(self) -> np.ndarray:
        return np.array(self.rows, float)

    def actuators(self, x):
        """N x: joint positions, velocities or accelerations (n,) in actuator coordinates."""
        return jnp.asarray(self.matrix) @ x

    def joints(self, tau):
        """Nᵀ τ_a: actuator torques (n,) as joint torques (virtual work)."""
        return jnp.asarray(self.matrix).T @ tau

    def acting(self, torque, s, q, qd, qdd, *args):
        """`torque(s, N q, N q̇, N q̈, *args)`, an effect's torque on the actuators, on the joints."""
        return self.joints(torque(s, self.actuators(q), self.actuators(qd), self.actuators(qdd), *args))

    def describe(self, names: tuple[str, ...] = ()) -> str:
        """The statement that `parse` turns back into it, one actuator per item (those that turn
        with their own joint left out): `m2 = q2 - q1`."""
        N = self.matrix
        out = []
        for k, row in enumerate(N):
            if np.array_equal(row, np.eye(len(N))[k]):
                continue
            terms = []
            for j, c in enumerate(row):
                if c == 0:
                    continue
                name = names[j] if names else f"q{j + 1}"
                mag = "" if abs(c) == 1 else f"{abs(c):.12g} "
                terms.append(("- " if c < 0 else "+ ") + mag + name)
            text = " ".join(terms)
            out.append(f"m{k + 1} = " + (text[2:] if text.startswith("+ ") else "-" + text[1:]))
        return "; ".join(out)


def of_matrix(N, where: str = "transmission") -> Transmission | None:
    """The transmission of the matrix N (n, n), checked: None for the identity, a `ModelError` for
    a matrix that is not square, not finite or singular."""
    N = np.asarray(N, float)
    if N.ndim != 2 or N.shape[0] != N.shape[1] or N.size == 0:
        raise ModelError(f"{where}: N must be square (one actuator per joint), got shape {N.shape}")
    if not np.all(np.isfinite(N)):
        raise ModelError(f"{where}: N has an entry that is not a finite number")
    if np.linalg.matrix_rank(N) < len(N):
        raise ModelError(f"{where}: N = {N.tolist()} is singular: two actuators turn as one, or a joint with none")
    if np.array_equal(N, np.eye(len(N))):
        return None
    return Transmission(tuple(tuple(float(x) for x in row) for row in N))


_TERM = re.compile(r"\s*([+-]?)\s*((?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)?\s*\*?\s*([A-Za-z_][\w.]*)\s*")


def _combination(text: str, joint: dict[str, int], n: int, where: str) -> np.ndarray:
    """A row of N from `2 q1 - q2`."""
    row, pos = np.zeros(n), 0
    text = text.strip()
    if not text:
        raise ModelError(f"{where}: an empty combination of joints")
    while pos < len(text):
        m = _TERM.match(text, pos)
        if not m or m.end() == pos or (pos > 0 and not m.group(1)):
            raise ModelError(f"{where}: {text!r} is not a combination of joints such as q2 - q1 or 0.5 q5 + 0.5 q6")
        sign, coef, name = m.groups()
        if name not in joint:
            raise ModelError(f"{where}: unknown joint {name!r} (the joints are {', '.join(joint)})")
        row[joint[name]] += (-1.0 if sign == "-" else 1.0) * (float(coef) if coef else 1.0)
        pos = m.end()
    return row


def parse(text: str, n: int, names: tuple[str, ...] = (), where: str = "transmission") -> Transmission | None:
    """A statement (see the module) for `n` joints, named `q1`..`qn` or `names`: its transmission,
    None for the identity; a one-line `ModelError` for a malformed one."""
    text = text.strip()
    if text.startswith("["):
        try:
            N = json.loads(text)
        except ValueError:
            raise ModelError(f"{where}: {text!r} is not a matrix such as [[1, 0], [-1, 1]]") from None
        if np.asarray(N, dtype=object).shape != (n, n):
            raise ModelError(f"{where}: N must be {n}×{n} (one actuator per joint), got {text!r}")
        try:
            return of_matrix(N, where)
        except (TypeError, ValueError):
            raise ModelError(f"{where}: {text!r} has an entry that is not a number") from None
    joint = {f"q{j + 1}": j for j in range(n)} | {name: j for j, name in enumerate(names)}
    items = [x for x in text.split(";") if x.strip()]
    if not items:
        raise ModelError(f"{where}: empty (say how each actuator turns with the joints, e.g. q1; q2 - q1)")
    N, given = np.eye(n), set()
    for k, item in enumerate(items):
        head, eq, body = item.partition("=")
        if eq:
            m = re.fullmatch(r"\s*m(\d+)\s*", head)
            if not m:
                raise ModelError(f"{where}: {head.strip()!r} is not an actuator such as m2 (in {item.strip()!r})")
            k = int(m.group(1)) - 1
        else:
            body = item
        if not 0 <= k < n:
            raise ModelError(f"{where}: actuator {k + 1} of a structure with {n} joints (one actuator per joint)")
        if k in given:
            raise ModelError(f"{where}: actuator m{k + 1} stated twice")
        given.add(k)
        N[k] = _combination(body, joint, n, where)
    return of_matrix(N, where)


def of_urdf(path, joint_names: tuple[str, ...]) -> Transmission | None:
    """The transmission the URDF's `<transmission>` elements state for the chain's joints
    `joint_names`: a simple transmission θ = r q (r: the actuator's `mechanicalReduction` times the
    joint's, each 1 when not given), a differential θ_a = r_a (r_1 q_1 + r_2 q_2), θ_b = r_b (r_1
    q_1 − r_2 q_2) (ros_control's `DifferentialTransmission`); a joint without one turns its own
    actuator. Elements on joints off the chain (a gripper's) are left out; a `ModelError` for one
    that mixes them, or of another kind."""
    from manus.plants import urdf

    n, index = len(joint_names), {name: j for j, name in enumerate(joint_names)}
    N = np.eye(n)
    for t in urdf.transmissions(path):
        where = f"{path}: transmission {t.name}"
        on = [j for j, _ in t.joints if j in index]
        if not on:
            continue
        if len(on) != len(t.joints):
            off = [j for j, _ in t.joints if j not in index]
            raise ModelError(f"{where}: joints {', '.join(off)} are not in the chain ({', '.join(joint_names)})")
        (jr, ar) = ([r for _, r in t.joints], [r for _, r in t.actuators])
        rows = [index[j] for j, _ in t.joints]
        if len(t.joints) == 1 and len(t.actuators) == 1:
            block = np.array([[ar[0] * jr[0]]])
        elif len(t.joints) == 2 and len(t.actuators) == 2 and "differential" in t.kind.lower():
            block = np.array([[ar[0] * jr[0], ar[0] * jr[1]], [ar[1] * jr[0], -ar[1] * jr[1]]])
        else:
            raise ModelError(
                f"{where}: {t.kind or 'no type'} with {len(t.joints)} joint(s) and {len(t.actuators)} actuator(s): "
                "manus reads a simple transmission (one joint, one actuator) or a differential (two of each)"
            )
        if any(not np.array_equal(N[r], np.eye(n)[r]) for r in rows):
            raise ModelError(f"{where}: a joint of it has a transmission already")
        for a, r in enumerate(rows):
            N[r] = 0.0
            N[r, rows] = block[a]
    return of_matrix(N, f"{path}: transmissions")


def stated(structure: S, text: str | None, where: str = "transmission") -> S:
    """`structure` with the transmission `text` states (`parse`; its joints' names where it has
    them), replacing any it had; unchanged for None."""
    if text is None:
        return structure
    names = tuple(getattr(structure, "joint_names", ()))
    return with_transmission(structure, parse(text, structure.n_joints, names, where))


def with_transmission(structure: S, t: Transmission | None) -> S:
    """`structure` with the transmission `t` (None: none)."""
    if structure.transmission == t:
        return structure
    return dataclasses.replace(structure, transmission=t)
