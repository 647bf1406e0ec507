"""Joint structures: how the joints are coupled through inertia (the `rigid` effect).

A structure knows the inertia matrix H(q), the Coriolis/centripetal matrix C(q, q̇) written so
that Ḣ − 2C is skew-symmetric (the Slotine–Li form), and how to solve the small linear systems
of the simulator in closed form.

Two forms of the same definitions:

- the matrix form (`inertia`, `coriolis`, `rigid_torque`, `solve`, `friction_solve`) on arrays
  `(n,)` and `(n, n)`, for regressors and adaptation laws;
- the joint-tuple form used by the simulator's inner loop: every quantity is a tuple of per-joint
  scalars (`pose`, `shift`, `moved`, `mass`, `bias`, and the `Sym2`/`Diagonal` it returns), with
  2×2 algebra written out. Under `vmap` each scalar becomes a batch vector (structure of
  arrays), which XLA vectorizes; stacked (B, 2, 2) matrices would become a tiny matrix
  product per trial (docs/performance.md). `inertia` is built from `mass`.

Two structures:

- `Manus2`: the thesis's planar 2-link arm in *absolute* joint angles (both measured from the
  base frame, eqs. C.1–C.5). Rigid parameters a1, a2, a3 [kg m²]:

      H(q) = [[a1, a2 cos(q2 − q1)], [a2 cos(q2 − q1), a3]]
      C(q, q̇) q̇ = [−a2 sin(q2 − q1) q̇2², a2 sin(q2 − q1) q̇1²]

- `Axis(n)`: n independent single-axis joints (like the EMPS drive); one inertia (or mass)
  M_i per joint and no coupling.
"""

from __future__ import annotations

import abc
from typing import ClassVar, NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jax import Array

from manus.plants import fastmath

Joints = tuple  # one scalar (or batch vector) per joint


def joints(x: Array, n: int) -> Joints:
    """An array (n,) as a tuple of per-joint scalars."""
    return tuple(x[i] for i in range(n))


# Selects rather than jnp.clip/minimum/maximum: XLA's NaN-propagating min/max cost several
# instructions each on AVX2; for finite operands the results are the same.
def lesser(x, y):
    return jnp.where(y < x, y, x)


def greater(x, y):
    return jnp.where(y > x, y, x)


def clip(x, lo, hi):
    return jnp.where(x < lo, lo, jnp.where(x > hi, hi, x))


def median(x, y, z):
    return greater(lesser(x, y), lesser(greater(x, y), z))


class Sym2(NamedTuple):
    """A symmetric 2×2 matrix [[a, b], [b, d]], its algebra in closed form."""

    a: Array
    b: Array
    d: Array

    def matrix(self) -> Array:
        a, b, d = jnp.broadcast_arrays(self.a, self.b, self.d)
        return jnp.stack([jnp.stack([a, b]), jnp.stack([b, d])])

    def diagonal(self) -> Joints:
        return self.a, self.d

    def minus_diagonal(self, x: Joints) -> "Sym2":
        return Sym2(self.a - x[0], self.b, self.d - x[1])

    def det(self) -> Array:
        return self.a * self.d - self.b * self.b

    def solve(self, r: Joints) -> Joints:
        """H⁻¹ r (H = self)."""
        det = self.det()
        return (self.d * r[0] - self.b * r[1]) / det, (self.a * r[1] - self.b * r[0]) / det

    def friction(self, v: Joints, lo: Joints, hi: Joints, dt) -> Joints:
        """argmin ½ fᵀ W f − fᵀ v over the box −lo ≤ f ≤ hi, W = dt·H⁻¹ (H = self), exactly.

        Minimising over f2 first leaves a convex function of f1 whose derivative is
        continuous, increasing and piecewise linear: its zero is the median of the zeros of
        its three pieces (f2 free: the unconstrained optimum (H v / dt)_1; f2 at either bound:
        that edge's optimum). Clipped to f1's box it is f1*, and f2* is the optimum given f1*.
        With u = v·det(H)/dt the edge optima are (u1 + b f2)/d and (u2 + b f1)/a.
        """
        (v1, v2), (lo1, lo2), (hi1, hi2) = v, lo, hi
        a, b, d = self
        scale = self.det() * (1.0 / dt)
        u1, u2 = v1 * scale, v2 * scale
        g1 = (a * v1 + b * v2) * (1.0 / dt)
        f1 = clip(median((u1 - b * lo2) * (1.0 / d), (u1 + b * hi2) * (1.0 / d), g1), -lo1, hi1)
        return f1, clip((u2 + b * f1) * (1.0 / a), -lo2, hi2)


class Diagonal(NamedTuple):
    """A diagonal matrix diag(d)."""

    d: Joints

    def matrix(self) -> Array:
        return jnp.diag(jnp.stack(self.d))

    def diagonal(self) -> Joints:
        return self.d

    def minus_diagonal(self, x: Joints) -> "Diagonal":
        return Diagonal(tuple(a - b for a, b in zip(self.d, x)))

    def solve(self, r: Joints) -> Joints:
        return tuple(x / a for a, x in zip(self.d, r))

    def friction(self, v: Joints, lo: Joints, hi: Joints, dt) -> Joints:
        """The box QP of `Sym2.friction`, uncoupled: a clip per joint."""
        return tuple(clip(a * x * (1.0 / dt), -l, u) for a, x, l, u in zip(self.d, v, lo, hi))


class Structure(eqx.Module):
    """Abstract joint structure. Arrays are per joint, shape `(n_joints,)`."""

    name: ClassVar[str]
    n_joints: eqx.AbstractVar[int]

    @property
    @abc.abstractmethod
    def rigid_names(self) -> tuple[str, ...]:
        """Names of the rigid-body parameters, in regressor column order."""

    @property
    @abc.abstractmethod
    def rigid_defaults(self) -> tuple[float, ...]:
        """Default values of the rigid-body parameters (the thesis's where it has them)."""

    # -- joint-tuple form -------------------------------------------------------------------
    @abc.abstractmethod
    def pose(self, q: Joints) -> tuple:
        """What H and C need of the configuration q (manus2: cos and sin of q2 − q1)."""

    @abc.abstractmethod
    def shift(self, dq: Joints) -> tuple:
        """What `moved` needs of a small move dq (manus2: cos and sin of dq2 − dq1, for
        |dq2 − dq1| ≤ π/4, without range reduction)."""

    @abc.abstractmethod
    def moved(self, pose: tuple, shift: tuple) -> tuple:
        """The pose after the move `shift`: a rotation, no new sin/cos of large angles."""

    @abc.abstractmethod
    def mass(self, pose: tuple, p: dict) -> Sym2 | Diagonal:
        """H(q) in closed form."""

    @abc.abstractmethod
    def bias(self, pose: tuple, qd: Joints, p: dict) -> Joints:
        """C(q, q̇) q̇."""

    # -- matrix form ------------------------------------------------------------------------
    def inertia(self, q: Array, p: dict) -> Array:
        """H(q), shape (n, n)."""
        return self.mass(self.pose(joints(q, self.n_joints)), p).matrix()

    @abc.abstractmethod
    def coriolis(self, q: Array, qd: Array, p: dict) -> Array:
        """C(q, q̇), shape (n, n), with Ḣ − 2C skew-symmetric."""

    @abc.abstractmethod
    def _closed_form(self, H: Array) -> Sym2 | Diagonal:
        """The matrix H (n, n) in this structure's closed form."""

    def solve(self, H: Array, r: Array) -> Array:
        """H⁻¹ r in closed form."""
        return jnp.stack(self._closed_form(H).solve(joints(r, self.n_joints)))

    def friction_solve(self, H: Array, vstar: Array, lo: Array, hi: Array, dt) -> Array:
        """The friction torque f ∈ [−lo, hi] of one implicit time step.

        Solves min_f ½ fᵀ W f − fᵀ v* over the box, W = dt·H⁻¹: the exact Moreau step for
        Coulomb-type friction. The new velocity is v* − W f; a joint whose needed friction lies
        inside its bounds comes to rest exactly (stiction, no creep).
        """
        n = self.n_joints
        return jnp.stack(self._closed_form(H).friction(joints(vstar, n), joints(lo, n), joints(hi, n), dt))

    def violations(self, p: dict) -> list[str]:
        """The rules of physics the rigid parameters `p` break (H(q) positive definite)."""
        return []

    def rigid_torque(self, q: Array, qd: Array, qdd: Array, p: dict) -> Array:
        """H(q) q̈ + C(q, q̇) q̇."""
        return self.inertia(q, p) @ qdd + self.coriolis(q, qd, p) @ qd


class Manus2(Structure):
    """The MANUS-2 planar 2-link arm in absolute joint angles (thesis eqs. 3.2–3.4, C.1–C.5)."""

    name: ClassVar[str] = "manus2"
    n_joints: int = eqx.field(default=2, static=True)

    @property
    def rigid_names(self):
        return ("a1", "a2", "a3")

    @property
    def rigid_defaults(self):
        return (0.349, 0.241, 0.246)  # kg m², thesis §3.5.5 and eq. 3.13

    def pose(self, q):
        s, c = fastmath.sincos(q[1] - q[0])
        return c, s

    def shift(self, dq):
        s, c = fastmath.kernel_sincos(dq[1] - dq[0])
        return c, s

    def moved(self, pose, shift):
        (c, s), (cd, sd) = pose, shift
        return c * cd - s * sd, s * cd + c * sd

    def mass(self, pose, p):
        return Sym2(p["a1"], p["a2"] * pose[0], p["a3"])

    def bias(self, pose, qd, p):
        k = p["a2"] * pose[1]
        return -k * qd[1] * qd[1], k * qd[0] * qd[0]

    def coriolis(self, q, qd, p):
        k = p["a2"] * fastmath.sin(q[1] - q[0])
        z = 0 * k
        return jnp.stack([jnp.stack([z, -k * qd[1]]), jnp.stack([k * qd[0], z])])

    def _closed_form(self, H):
        return Sym2(H[0, 0], H[0, 1], H[1, 1])

    def violations(self, p):
        a1, a2, a3 = (float(p[k]) for k in self.rigid_names)
        if a1 > 0 and a3 > 0 and a1 * a3 > a2 * a2:
            return []
        return [f"a1 = {a1:.4g}, a2 = {a2:.4g}, a3 = {a3:.4g}: H(q) is not positive definite for every q "
                "(a1 > 0, a3 > 0, a1 a3 > a2² needed)"]


class Axis(Structure):
    """`n_joints` independent single axes (rotary or prismatic), one inertia M_i each."""

    name: ClassVar[str] = "axis"
    n_joints: int = eqx.field(default=1, static=True)

    @property
    def rigid_names(self):
        return tuple(f"M{i + 1}" for i in range(self.n_joints))

    @property
    def rigid_defaults(self):
        return (1.0,) * self.n_joints  # thesis eq. 4.1: m = 1 kg near the workspace centre

    def pose(self, q):
        return ()

    def shift(self, dq):
        return ()

    def moved(self, pose, shift):
        return ()

    def mass(self, pose, p):
        return Diagonal(tuple(jnp.asarray(p[k]) for k in self.rigid_names))

    def bias(self, pose, qd, p):
        return tuple(jnp.zeros_like(v) for v in qd)

    def coriolis(self, q, qd, p):
        return jnp.zeros((self.n_joints, self.n_joints), qd.dtype)

    def _closed_form(self, H):
        return Diagonal(joints(jnp.diagonal(H), self.n_joints))

    def violations(self, p):
        return [f"{k} = {float(p[k]):.4g}: an inertia must be positive" for k in self.rigid_names if not float(p[k]) > 0]


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
        from manus.plants.errors import ModelError
        from manus.plants.serial import Serial

        if robot is None:
            raise ModelError("structure urdf needs the robot's URDF file (a recording's '# robot: PATH', or --robot FILE.urdf)")
        serial = Serial.from_urdf(robot)
        if serial.n_joints != n_joints:
            raise ModelError(f"{robot}: the URDF's chain has {serial.n_joints} joints ({', '.join(serial.joint_names)}), "
                             f"not {n_joints}")
        return serial
    raise ValueError(f"unknown structure {name!r}: expected 'manus2', 'axis' or 'urdf'")
