"""What the hardware loop never lets a rig do (`Limits`), and the check that trips it (`check`).

A person holds the handle. The loop clamps every command to the torque limit, and stops at zero
torque, latched for the rest of the run, the first tick any joint:

- moves faster than `velocity` (a runaway: a wrong gain, a sign error, a driver fault);
- leaves the workspace box (`low`..`high`, or the start position ± `span`);
- jumps by more than `jump` in one tick (an encoder glitch, a broken line: no arm moves so far in
  a millisecond; checked first, since a jump also reads as a speed);
- is held at `STALL_SHARE` of the torque limit or more, moving slower than `stall_speed`, for
  `stall_seconds` (a stall: the arm pressed against an obstacle, or against the person);

and the loop stops the same way when it cannot keep up: more than `missed` of its commands late
(sent more than a period after their sample) or more than `lost` of the samples lost, over the
last `window` seconds (a loop starved by other work, a failing link: the controller no longer
acts at the rate its gains were set for).

The limits are the user's: a rig file (`Limits.read`, TOML, a `[limits]` table) or the defaults,
which are safe for the thesis arm (MANUS-2: its actuators characterised at 6.7–6.8 N·m, 30 rpm
≈ 3.1 rad/s a "moderate" speed of its amplifiers, the workspace centre at q = (0.464, 2.409)
rad). The torque limit is never the device's alone: the loop uses the smaller of the two.

`check` is one pure function of arrays, run twice each tick: inside the compiled tick (jnp) and
again by the loop on what it received and sent (numpy), so that neither a wrong compiled step nor
a wrong loop lets a fault through alone.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from manus.plants.errors import ManusError

TRIPS = ("", "non-finite", "velocity", "workspace", "jump", "stall", "loop")  # a trip's code is its index here
NONFINITE, VELOCITY, WORKSPACE, JUMP, STALL, LOOP = 1, 2, 3, 4, 5, 6
STALL_SHARE = 0.95  # a joint commanded at least this share of the torque limit pushes as hard as it may


@dataclass(frozen=True)
class Limits:
    """The limits of one rig (per joint, the same for every joint unless `low`/`high` say otherwise)."""

    torque: float = 7.0  # |τ| [N·m]
    velocity: float = 4.0  # |q̇| [rad/s]
    span: float = 1.0  # the workspace: the start position ± this [rad], where `low`/`high` are not given
    low: tuple[float, ...] | None = None  # the workspace box [rad], per joint
    high: tuple[float, ...] | None = None
    jump: float = 0.1  # |Δq| in one tick [rad] (at 4 rad/s and 1 kHz a joint moves 0.004 rad)
    stall_seconds: float = 0.5
    stall_speed: float = 0.05  # [rad/s]
    missed: float = 0.05  # the share of late commands ...
    lost: float = 0.05  # ... or of lost samples ...
    window: float = 1.0  # ... over this many seconds that stops the loop

    def __post_init__(self):
        for name in ("missed", "lost"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value <= 1:
                raise ManusError(f"limits: {name} is a share of the window, in (0, 1], got {value!r}")
        for name in ("torque", "velocity", "span", "jump", "stall_seconds", "stall_speed", "window"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or value <= 0:
                raise ManusError(f"limits: {name} must be a positive finite number, got {value!r}")
        if (self.low is None) != (self.high is None):
            raise ManusError("limits: the workspace needs both low and high (or neither: the start ± span)")
        if self.low is not None and self.high is not None:
            low, high = np.asarray(self.low, float), np.asarray(self.high, float)
            if low.shape != high.shape or low.ndim != 1 or not np.all(np.isfinite(low) & np.isfinite(high)):
                raise ManusError(f"limits: low {list(self.low)} and high {list(self.high)}: one finite bound per joint")
            if np.any(low >= high):
                raise ManusError(f"limits: the workspace's low {list(self.low)} must be under high {list(self.high)}")

    @classmethod
    def read(cls, path: str | Path) -> Limits:
        """The `[limits]` table of a TOML rig file: any of torque, velocity, span, low, high, jump,
        stall_seconds, stall_speed (the others stay at their defaults)."""
        import tomllib

        path = Path(path)
        try:
            table = tomllib.loads(path.read_text(encoding="utf-8")).get("limits")
        except FileNotFoundError:
            raise ManusError(f"{path}: no such rig file") from None
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            raise ManusError(f"{path}: not a readable TOML rig file ({e})") from None
        if not isinstance(table, dict):
            raise ManusError(f"{path}: no [limits] table (e.g. '[limits]' then 'torque = 5.0')")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - known)
        if unknown:
            raise ManusError(f"{path}: unknown limit(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items()}
        try:
            return cls(**values)  # pyright: ignore[reportArgumentType] (checked in __post_init__)
        except ManusError as e:
            raise ManusError(f"{path}: {e}") from None
        except TypeError as e:
            raise ManusError(f"{path}: {e}") from None

    def resolved(self, n: int, start: np.ndarray, device_torque: float, dt: float) -> Resolved:
        """These limits for a run of `n` joints starting at `start` [rad], the device's own torque
        limit (used where smaller) and its period `dt`."""
        if self.low is not None and self.high is not None:
            if len(self.low) != n:
                raise ManusError(f"limits: a workspace of {len(self.low)} joint(s) for a device of {n}")
            low, high = np.asarray(self.low, float), np.asarray(self.high, float)
        else:
            low, high = np.asarray(start, float) - self.span, np.asarray(start, float) + self.span
        torque = min(self.torque, device_torque) if math.isfinite(device_torque) and device_torque > 0 else self.torque
        return Resolved(
            torque,
            self.velocity,
            low,
            high,
            self.jump,
            self.stall_seconds,
            self.stall_speed,
            dt,
            self.missed,
            self.lost,
            max(1, round(self.window / dt)),
        )


@dataclass(frozen=True)
class Resolved:
    """`Limits` made concrete for one run (`Limits.resolved`): arrays per joint, the torque the
    smaller of the user's and the device's."""

    torque: float
    velocity: float
    low: np.ndarray
    high: np.ndarray
    jump: float
    stall_seconds: float
    stall_speed: float
    dt: float
    missed: float
    lost: float
    window: int  # ticks


def check(lim: Resolved, q, q_prev, ticks, tau_prev, held, xp=np):
    """One tick's limits: positions `q` now and `q_prev` `ticks` samples before (1, more after
    lost samples), the command applied since (`tau_prev`, clamped) and how long each joint has
    been held still at the torque limit (`held` [s]). Returns (code, joint, held now): the trip's
    code (`TRIPS`; 0: none) on the first joint that trips (0-based), in the order jump, velocity,
    workspace, stall. `xp`: numpy or jax.numpy (the same rule in the compiled tick and the loop)."""
    span = ticks * lim.dt
    dq = q - q_prev
    speed = xp.abs(dq) / span
    held = xp.where((xp.abs(tau_prev) >= STALL_SHARE * lim.torque) & (speed < lim.stall_speed), held + span, 0.0)
    code = xp.where(
        xp.abs(dq) > lim.jump * ticks,
        JUMP,
        xp.where(
            speed > lim.velocity,
            VELOCITY,
            xp.where((q < lim.low) | (q > lim.high), WORKSPACE, xp.where(held >= lim.stall_seconds - 1e-9, STALL, 0)),
        ),
    )
    joint = xp.argmax(code > 0)
    return code[joint], joint, held


def reason(code: int, joint: int, lim: Resolved, q, q_prev, ticks: int, t: float) -> str:
    """The sentence a trip is reported with."""
    j = int(joint)
    at = f"joint {j + 1} at t = {t:.4g} s"
    if code == JUMP:
        return f"encoder jump: {at} moved {abs(q[j] - q_prev[j]):.4g} rad in one tick (limit {lim.jump:g})"
    if code == VELOCITY:
        speed = abs(q[j] - q_prev[j]) / (ticks * lim.dt)
        return f"velocity limit: {at} moved at {speed:.4g} rad/s (limit {lim.velocity:g})"
    if code == WORKSPACE:
        return f"workspace limit: {at} reached q = {q[j]:.4g} rad, outside [{lim.low[j]:.4g}, {lim.high[j]:.4g}]"
    if code == STALL:
        return f"stall: {at} held at the torque limit ({lim.torque:g} N·m) without moving for {lim.stall_seconds:g} s"
    return "non-finite value (a measurement, the controller's state or its command)"
