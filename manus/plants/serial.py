"""Serial chains of revolute and prismatic joints, from a URDF: any robot arm's `rigid` effect.

`Serial` is a `Structure` in the URDF's own *relative* joint coordinates (each joint measured
from its parent link, as pinocchio and the robot's controller count them). Its rigid torque is

    τ = H(q) q̈ + C(q, q̇) q̇ + g(q) + diag(Ia) q̈

computed by the recursive Newton–Euler algorithm (RNEA) in JAX (jit- and vmap-able, float64
when x64 is on). Gravity is part of `rigid` for serial chains: its parameters are the links'
masses and first moments.

## Frames and parameters

Link j is the body that joint j (1-based, root to tip) moves, with the URDF frame of joint j's
child link; links attached through fixed joints (and branches locked at their zero position, as a
gripper's fingers) are merged into it. Its *standard inertial parameters*, in its own frame [SI]:

| name | meaning | unit |
|---|---|---|
| `m{j}` | mass | kg |
| `mx{j}`, `my{j}`, `mz{j}` | first moment m·c (c: centre of mass) | kg m |
| `Ixx{j}`, `Ixy{j}`, `Ixz{j}`, `Iyy{j}`, `Iyz{j}`, `Izz{j}` | inertia tensor about the frame's *origin* (1) | kg m² |

(1) The link frame's origin, not the centre of mass; `Ixy` is the tensor entry, as in the URDF.

followed by one armature per joint, `Ia{j}` [kg m² or kg]: the motor's rotor inertia reflected
through the gear, a torque Ia_j q̈_j on joint j alone. Parameter order (`rigid_names`): the ten of
link 1, ..., the ten of link n, then Ia1..Ian. Pinocchio orders a link's ten as m, mx, my, mz,
Ixx, Ixy, Iyy, Ixz, Iyz, Izz (Iyy and Ixz swapped), about the same origin.

The torque is linear in these parameters: the regressor is written in closed form from the
RNEA's outward pass (each link's wrench regressor, summed over the joints it loads), and tested
against the RNEA and pinocchio.

## What else is here

- The effect protocol: `Model(serial, "rigid,viscous,coulomb,offset")` holds the chain's rigid
  effect (gravity included) and the per-joint effects, each acting on its joint's own relative
  coordinate (b_i q̇_i, Fc_i sgn(q̇_i), ...). The per-joint cos/sin `gravity` effect does not apply
  (`rigid_gravity` says why: gravity is part of rigid here).
- The simulator's joint-tuple form (`pose`, `mass`, `bias`): `manus.plants.simulator.Simulator`
  takes a serial chain, its H(q) dense and its coupled stick-slip step the box QP of
  `manus.plants.serial_friction`; `manus.plants.serial_sim` drives it into a recording.
- `base_parameters`: the identifiable combinations of the standard parameters (Gautier's
  numerical method: QR with column pivoting of a regressor stacked over random states), and
  `SerialBase`, the chain in those parameters: the structure `manus fit` identifies.
- `SerialPseudo`: the chain in pseudo-inertia coordinates (`manus.plants.pseudo_inertia`), the
  structure adaptive control adapts (`Serial.adaptive_form`).

The URDF file itself is read by `manus.plants.urdf`.
"""

from __future__ import annotations

import abc
import os
from typing import TYPE_CHECKING, ClassVar, NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from manus.plants import urdf
from manus.plants.errors import ModelError
from manus.plants.pseudo_inertia import ENTRIES, OFF_DIAGONAL, entries_of, standard_of
from manus.plants.serial_friction import Dense
from manus.plants.structures import Admissible, Structure
from manus.plants.transmission import of_urdf as urdf_transmission
from manus.stored import stored_jit

LINK_PARAMETERS = ("m", "mx", "my", "mz", "Ixx", "Ixy", "Ixz", "Iyy", "Iyz", "Izz")
GRAVITY = (0.0, 0.0, -9.81)  # m/s², the world's z axis up
Vector = Array | np.ndarray  # a chain's q, q̇, q̈ or parameters: JAX's or numpy's
GRAVITY_IN_RIGID = (
    "a serial chain's gravity is part of rigid (the links' masses and first moments in the "
    "world's gravity): a cos/sin of each relative joint angle is not a physical effect there"
)


# -- the structure ----------------------------------------------------------------------------------


def _cross_matrix(x: Array) -> Array:
    """[x]× (..., 3, 3): [x]× y = x × y, for x (..., 3)."""
    z = jnp.zeros_like(x[..., 0])
    return jnp.stack(
        [
            jnp.stack([z, -x[..., 2], x[..., 1]], -1),
            jnp.stack([x[..., 2], z, -x[..., 0]], -1),
            jnp.stack([-x[..., 1], x[..., 0], z], -1),
        ],
        -2,
    )


def _rotation(axis: Array, angle: Array) -> Array:
    """Rotation by `angle` about the unit vector `axis` (Rodrigues)."""
    K = _cross_matrix(axis)
    return jnp.eye(3) + jnp.sin(angle) * K + (1 - jnp.cos(angle)) * (K @ K)


def _mv(A: Array, x: Array | np.ndarray) -> Array:
    """A x for 3×3 matrices A (..., 3, 3), as products and sums (XLA compiles these faster than small dots)."""
    return (A * x[..., None, :]).sum(-1)


def _inertia_tensor(t: Array | np.ndarray) -> Array:
    """The inertia tensor (..., 3, 3) of ten standard parameters (..., 10)."""
    return jnp.stack([t[..., 4:7], t[..., (5, 7, 8)], t[..., (6, 8, 9)]], -2)


def _times_inertia(x: Array) -> Array:
    """L(x) (..., 3, 6) with I x = L(x) (Ixx, Ixy, Ixz, Iyy, Iyz, Izz)."""
    x0, x1, x2 = x[..., 0], x[..., 1], x[..., 2]
    z = jnp.zeros_like(x0)
    return jnp.stack(
        [
            jnp.stack([x0, x1, x2, z, z, z], -1),
            jnp.stack([z, x0, z, x1, x2, z], -1),
            jnp.stack([z, z, x0, z, x1, x2], -1),
        ],
        -2,
    )


class Motion(NamedTuple):
    """Each link's motion (arrays (n, ...)): its placement in its parent's frame (R, p), its
    angular velocity w, angular acceleration dw and its origin's linear acceleration a (gravity
    included as the root's upward acceleration) in its own frame, and its placement in the root
    link's frame (R0, o0)."""

    R: Array
    p: Array
    w: Array
    dw: Array
    a: Array
    R0: Array
    o0: Array


@stored_jit
def _regressors(serial, q, qd, qdd):
    """The chain's regressor at each sample of q, q̇, q̈ (m, n)."""
    return jax.vmap(serial.regressor)(q, qd, qdd)


@stored_jit
def _mass_matrices(serial, q, theta):
    """H(q) at each configuration of q (m, n): compiled once per chain, not once per call."""
    return jax.vmap(lambda x: serial.mass_matrix(x, theta))(q)


class _Configuration(Structure):
    """A serial chain, in any of its parametrizations: the simulator's joint-tuple form of a chain
    whose pose is its configuration itself (H and C are computed from q each time); its mass matrix
    is dense (`serial_friction.Dense`). Gravity is part of its rigid effect (`rigid_gravity`)."""

    name: ClassVar[str] = "urdf"
    rigid_gravity: ClassVar[str] = GRAVITY_IN_RIGID

    def pose(self, q):
        return tuple(q)

    def shift(self, dq):
        return tuple(dq)

    def moved(self, pose, shift):
        return tuple(a + b for a, b in zip(pose, shift, strict=True))


MAX_LINKS = 500  # a URDF's links at most (its walks recurse once per link)


class Serial(_Configuration):
    """A serial chain of revolute and prismatic joints in relative joint coordinates (q [rad or m]).

    Configuration (numpy float64 arrays: JAX takes them in the precision of the computation): each
    joint's fixed placement in its parent link's frame (`rotation` (n, 3, 3),
    `translation` (n, 3) [m]), its unit `axis` (n, 3) in its own frame, which joints are
    `prismatic`, the world's `gravity` (3,) [m/s²] in the root link's frame, and the URDF's
    parameter values (`defaults`, (11 n,), the order of `rigid_names`). Build it with
    `Serial.from_urdf`.
    """

    n_joints: int = eqx.field(static=True)
    joint_names: tuple[str, ...] = eqx.field(static=True)
    prismatic: tuple[bool, ...] = eqx.field(static=True)
    rotation: np.ndarray
    translation: np.ndarray
    axis: np.ndarray
    gravity: np.ndarray
    defaults: np.ndarray
    source: str = eqx.field(default="", static=True)  # the URDF file it was read from (absolute)
    # the joints' <dynamics damping friction>: the nominal viscous and Coulomb friction (0: none given)
    damping: tuple[float, ...] = eqx.field(default=(), static=True)
    friction: tuple[float, ...] = eqx.field(default=(), static=True)

    @classmethod
    def from_urdf(cls, path, tip: str | None = None, armature=None, gravity=GRAVITY) -> Serial:
        """The serial chain of a URDF file.

        The chain runs from the root link down the movable joints; fixed joints merge their child
        link into the parent. Where the tree branches into several movable joints (a gripper's
        fingers) the chain ends, and the branches are locked at their zero position and merged,
        unless `tip` names the link the chain must reach. `armature` (one per joint
        [kg m² or kg]) overrides the `armature` attribute of the joints' `<dynamics>` (default 0).
        The URDF's `<transmission>` elements give the chain's transmission
        (`manus.plants.transmission.of_urdf`).
        `gravity` [m/s²] is given in the root link's frame. A file that is not such a URDF is
        refused with a `ModelError` that names the file and the problem.
        """
        try:
            return cls._from_urdf(path, tip, armature, gravity)
        except (ValueError, TypeError, AttributeError, KeyError, ZeroDivisionError) as e:
            what = f"missing {e}" if isinstance(e, KeyError) else str(e)
            raise ModelError(f"{path}: not a well-formed URDF ({type(e).__name__}: {what})") from None

    @classmethod
    def _from_urdf(cls, path, tip, armature, gravity) -> Serial:
        links, joints = urdf.read(path)
        if len(links) > MAX_LINKS:
            raise ModelError(f"{path}: {len(links)} links; a robot's URDF has at most {MAX_LINKS} here")
        children = {name: [] for name in links}
        parents: dict[str, str] = {}
        for j in joints.values():
            if j.parent == j.child:
                raise ModelError(f"{path}: joint {j.name} joins the link {j.child!r} to itself")
            if j.child in parents:
                raise ModelError(
                    f"{path}: the link {j.child!r} is the child of two joints ({parents[j.child]}, {j.name}): "
                    "a URDF is a tree, without loops"
                )
            parents[j.child] = j.name
            if j.kind not in ("revolute", "continuous", "prismatic", "fixed"):
                raise ModelError(
                    f"{path}: joint {j.name} is {j.kind}; a serial chain takes revolute, "
                    "continuous, prismatic and fixed joints"
                )
            if j.parent not in links or j.child not in links:
                missing = j.parent if j.parent not in links else j.child
                raise ModelError(f"{path}: joint {j.name} names the link {missing!r}, which the URDF does not have")
            children[j.parent].append(j)
        roots = set(links) - {j.child for j in joints.values()}
        if len(roots) != 1:
            raise ModelError(f"{path}: expected one root link, found {sorted(roots)}")
        if tip is not None and tip not in links:
            raise ModelError(f"{path}: no link named {tip!r}")

        def reaches(link: str) -> bool:
            return link == tip or any(reaches(j.child) for j in children[link])

        def movable_below(link: str) -> list[urdf.Joint]:
            """The movable joints reached from `link` through fixed joints only."""
            out = []
            for j in children[link]:
                out += [j] if j.kind != "fixed" else movable_below(j.child)
            return out

        chain, body, inertials = [], next(iter(roots)), []
        while True:
            candidates = movable_below(body)
            if tip is not None:
                candidates = [j for j in candidates if reaches(j.child)]
            if len(candidates) != 1:
                break
            chain.append(candidates[0])
            body = candidates[0].child
        if not chain:
            branches = (
                f" (it branches into {', '.join(j.name for j in candidates)}: name the tip link)" if candidates else ""
            )
            raise ModelError(f"{path}: no chain of movable joints from the root link{branches}")

        def collect(link: str, R: np.ndarray, p: np.ndarray, stop: set) -> np.ndarray:
            """The ten parameters of `link` and everything rigidly attached (joints in `stop` end it)."""
            try:
                own = urdf.link_inertial(links[link])
            except ModelError as e:
                raise ModelError(f"{path}: {e}") from None
            theta = urdf.moved(own, R, p)
            for j in children[link]:
                if j.name not in stop:  # fixed, or a locked branch (zero position: its origin alone)
                    theta = theta + collect(j.child, R @ j.R, R @ j.p + p, stop)
            return theta

        def placement(joint: urdf.Joint) -> tuple[np.ndarray, np.ndarray]:
            """The joint's frame in the frame of the previous chain joint's child (or the root)."""
            start = chain[chain.index(joint) - 1].child if chain.index(joint) else next(iter(roots))
            R, p, link = joint.R, joint.p, joint.parent
            while link != start:
                up = next(j for j in joints.values() if j.child == link)
                R, p, link = up.R @ R, up.R @ p + up.p, up.parent
            return R, p

        stop = {j.name for j in chain}
        for j in chain:
            if j.mimic:
                raise ModelError(
                    f"{path}: joint {j.name} mimics another joint; a serial chain takes independent joints"
                )
            inertials.append(collect(j.child, np.eye(3), np.zeros(3), stop))
        n = len(chain)
        arm = np.array([j.armature for j in chain] if armature is None else armature, dtype=float)
        if arm.shape != (n,):
            raise ModelError(f"armature: expected {n} values (one per joint), got {arm.shape}")
        placements = [placement(j) for j in chain]
        return cls(
            n_joints=n,
            joint_names=tuple(j.name for j in chain),
            prismatic=tuple(j.kind == "prismatic" for j in chain),
            rotation=np.stack([R for R, _ in placements]),
            translation=np.stack([p for _, p in placements]),
            axis=np.stack([j.axis for j in chain]),
            gravity=np.asarray(gravity, dtype=float),
            defaults=np.concatenate([*inertials, arm]),
            source=os.path.abspath(path),  # (one file, one name: however a recording reaches it)
            damping=tuple(j.damping for j in chain),
            friction=tuple(j.friction for j in chain),
            transmission=urdf_transmission(path, tuple(j.name for j in chain)),
        )

    # -- parameters -------------------------------------------------------------------------
    @property
    def rigid_names(self):
        n = self.n_joints
        return tuple(f"{k}{j + 1}" for j in range(n) for k in LINK_PARAMETERS) + tuple(f"Ia{j + 1}" for j in range(n))

    @property
    def rigid_defaults(self):
        return tuple(float(v) for v in np.asarray(self.defaults))

    def theta(self, p: dict) -> Array:
        """The parameter vector (11 n,) in the order of `rigid_names`, from a dict."""
        return jnp.stack([jnp.asarray(p[k]) for k in self.rigid_names])

    # -- dynamics on the parameter vector -----------------------------------------------------
    def motion(self, q: Vector, qd: Vector, qdd: Vector, gravity: bool = True) -> Motion:
        """The outward pass of the RNEA: each link's velocity and acceleration from its parent's.

        Revolute joint (axis s, link frame = joint frame): ω = Rᵀω_p + s q̇,
        ω̇ = Rᵀω̇_p + (Rᵀω_p) × s q̇ + s q̈, a = Rᵀ(a_p + ω̇_p × p + ω_p × (ω_p × p)); a prismatic
        joint moves the origin along s instead: ω = Rᵀω_p, ω̇ = Rᵀω̇_p,
        a = Rᵀ(a_p + ...) + 2 ω × s q̇ + s q̈. The root accelerates at −g (`gravity=False`: 0).
        """
        slide = jnp.asarray(self.prismatic, jnp.result_type(qd, self.axis))  # 1: prismatic, 0: revolute
        turn = 1 - slide

        def outward(parent, x):
            w, dw, a, R0, o0 = parent  # the parent's, in the parent's frame
            E, p, s, slide, turn, q, qd, qdd = x
            R, p = E @ _rotation(s, turn * q), p + slide * _mv(E, s) * q
            a = _mv(R.T, a + jnp.cross(dw, p) + jnp.cross(w, jnp.cross(w, p)))
            w, dw = _mv(R.T, w), _mv(R.T, dw)
            a = a + slide * (2 * jnp.cross(w, s * qd) + s * qdd)
            dw = dw + turn * (jnp.cross(w, s * qd) + s * qdd)
            w = w + turn * s * qd
            link = (w, dw, a, R0 @ R, o0 + _mv(R0, p))
            return link, (R, p, *link)

        zero = jnp.zeros(3, slide.dtype)
        root = (zero, zero, zero - self.gravity if gravity else zero, jnp.eye(3, dtype=zero.dtype), zero)
        _, links = jax.lax.scan(outward, root, (self.rotation, self.translation, self.axis, slide, turn, q, qd, qdd))
        return Motion(*links)

    def rnea(self, q: Vector, qd: Vector, qdd: Vector, theta: Vector, gravity: bool = True) -> Array:
        """Inverse dynamics τ (n,) [N·m or N] by the recursive Newton–Euler algorithm.

        After the outward pass (`motion`), each link's wrench about its origin in its own frame,
        f = m a + ω̇ × h + ω × (ω × h), n = I ω̇ + ω × I ω + h × a (h = m c, I about the origin),
        accumulates inward, and each joint takes its axis's component (moment or force).
        `gravity=False` leaves g out.
        """
        n = self.n_joints
        links = theta[: 10 * n].reshape(n, 10)
        M = self.motion(q, qd, qdd, gravity)
        m, h, I = links[:, :1], links[:, 1:4], _inertia_tensor(links)
        f = m * M.a + jnp.cross(M.dw, h) + jnp.cross(M.w, jnp.cross(M.w, h))
        torque = _mv(I, M.dw) + jnp.cross(M.w, _mv(I, M.w)) + jnp.cross(h, M.a)

        def inward(child, x):  # the child's wrench, in this link's frame
            R, p, f, torque, s, slide = x
            f, torque = f + child[0], torque + child[1]
            return (_mv(R, f), _mv(R, torque) + jnp.cross(p, _mv(R, f))), (s * jnp.where(slide, f, torque)).sum()

        zero = jnp.zeros(3, f.dtype)
        slide = jnp.asarray(self.prismatic)
        _, tau = jax.lax.scan(inward, (zero, zero), (M.R, M.p, f, torque, self.axis, slide), reverse=True)
        return tau + theta[10 * n :] * qdd

    def mass_matrix(self, q: Vector, theta: Vector) -> Array:
        """H(q) (n, n), armature included, by composite inertias in the root frame.

        Joint i's unit motion is the twist ξ_i = S_i (as in `regressor`: (o0_i × s0_i, s0_i) for a
        revolute joint, (s0_i, 0) for a prismatic one), link k's spatial inertia about the root's
        origin M_k = [[m 1, −[h0]×], [[h0]×, I0]] (h0, I0: its first moment and inertia about that
        origin, in the root frame), and H_ij = ξ_iᵀ (Σ_{k ≥ max(i, j)} M_k) ξ_j: the links beyond
        both joints are the ones both move.
        """
        n = self.n_joints
        zero = jnp.zeros_like(q)
        M = self.motion(q, zero, zero, gravity=False)
        links = theta[: 10 * n].reshape(n, 10)
        m, h, I = links[:, 0], links[:, 1:4], _inertia_tensor(links)
        Rh = _mv(M.R0, h)
        Io = M.R0 @ I @ jnp.swapaxes(M.R0, -1, -2)
        So, Sh = _cross_matrix(M.o0), _cross_matrix(Rh)
        T = lambda A: jnp.swapaxes(A, -1, -2)
        I0 = Io + T(So) @ Sh + T(Sh) @ So + m[:, None, None] * (T(So) @ So)  # parallel axes to the root's origin
        h0 = Rh + m[:, None] * M.o0
        H0 = _cross_matrix(h0)
        eye = jnp.broadcast_to(jnp.eye(3, dtype=I0.dtype), I0.shape) * m[:, None, None]
        spatial = jnp.concatenate([jnp.concatenate([eye, -H0], -1), jnp.concatenate([H0, I0], -1)], -2)  # (n, 6, 6)
        composite = jnp.cumsum(spatial[::-1], 0)[::-1]  # Σ over the links from k to the tip
        s0 = _mv(M.R0, self.axis)
        slide = jnp.asarray(self.prismatic)[:, None]
        S = jnp.concatenate([jnp.where(slide, s0, jnp.cross(M.o0, s0)), jnp.where(slide, 0.0, s0)], -1)  # (n, 6)
        F = jnp.einsum("jab,jb->ja", composite, S)  # the force joint j's unit motion asks of the links beyond it
        upper = jnp.asarray(np.less_equal.outer(np.arange(n), np.arange(n)))  # i ≤ j: H_ij = S_i · F_j
        H = S @ F.T
        return jnp.where(upper, H, H.T) + jnp.diag(theta[10 * n :])

    def coriolis_times(self, q: Array, qd: Array, v: Array, theta: Array) -> Array:
        """C(q, q̇) v (n,) for the C of the Christoffel symbols of the first kind, C_ij = Σ_k c_ijk q̇_k,
        c_ijk = ½ (∂H_ij/∂q_k + ∂H_ik/∂q_j − ∂H_jk/∂q_i), the one for which Ḣ − 2C is skew-symmetric.

        c_ijk is symmetric in j and k, so (x, y) ↦ Σ_jk c_ijk x_j y_k is the symmetric bilinear form
        of the RNEA's velocity term c(q, q̇) = C(q, q̇) q̇ (a quadratic form in q̇), and polarization
        gives it from two RNEAs without gravity: C(q, q̇) v = ¼ [c(q, q̇ + v) − c(q, q̇ − v)].
        """
        zero = jnp.zeros_like(q)
        c = lambda u: self.rnea(q, u, zero, theta, gravity=False)
        return 0.25 * (c(qd + v) - c(qd - v))

    def slotine_li(self, q: Array, qd: Array, qd_r: Array, qdd_r: Array, theta: Array) -> Array:
        """H(q) q̈_r + C(q, q̇) q̇_r + g(q) (n,): the Slotine–Li torque (q̇_r, q̈_r: reference)."""
        zero = jnp.zeros_like(q)
        return self.rnea(q, zero, qdd_r, theta) + self.coriolis_times(q, qd, qd_r, theta)

    # -- regressors ---------------------------------------------------------------------------
    def regressor(self, q: Vector, qd: Vector, qdd: Vector, gravity: bool = True) -> Array:
        """Y (n, 11 n) with τ = Y θ (θ in the order of `rigid_names`), in closed form.

        Link j's wrench about its origin is linear in its ten parameters, (f, n) = A_j θ_j with
        A_j = [[a, [ω̇]× + [ω]×[ω]×, 0], [0, −[a]×, L(ω̇) + [ω]× L(ω)]] (6 × 10, L(x): I x = L(x)·I);
        moved to the root frame about the root's origin it is W_j = [[R0, 0], [[o0]× R0, R0]] A_j,
        and joint i ≤ j takes S_i · W_j with S_i its axis as a screw in the root frame:
        (o0_i × s0_i, s0_i) against (force, moment) for a revolute joint, (s0_i, 0) for a prismatic.
        """
        n = self.n_joints
        M = self.motion(q, qd, qdd, gravity)
        Ww, Wdw = _cross_matrix(M.w), _cross_matrix(M.dw)
        zeros = jnp.zeros((n, 3, 6), M.a.dtype)
        A = jnp.concatenate(
            [
                jnp.concatenate([M.a[:, :, None], Wdw + Ww @ Ww, zeros], -1),
                jnp.concatenate(
                    [
                        jnp.zeros_like(M.a)[:, :, None],
                        -_cross_matrix(M.a),
                        _times_inertia(M.dw) + Ww @ _times_inertia(M.w),
                    ],
                    -1,
                ),
            ],
            -2,
        )  # (n, 6, 10)
        force, moment = M.R0 @ A[:, :3], M.R0 @ A[:, 3:]
        W = jnp.concatenate([force, moment + _cross_matrix(M.o0) @ force], -2)  # (n, 6, 10)
        s0 = _mv(M.R0, self.axis)
        slide = jnp.asarray(self.prismatic)[:, None]
        S = jnp.concatenate([jnp.where(slide, s0, jnp.cross(M.o0, s0)), jnp.where(slide, 0.0, s0)], -1)  # (n, 6)
        loads = jnp.triu(jnp.ones((n, n), S.dtype))  # link j loads the joints up to j only
        Y = jnp.einsum("ik,jkp->ijp", S, W) * loads[:, :, None]
        return jnp.concatenate([Y.reshape(n, 10 * n), jnp.diag(qdd)], -1)

    def slotine_li_regressor(self, q: Array, qd: Array, qd_r: Array, qdd_r: Array) -> Array:
        """Y (n, 11 n) with H(q) q̈_r + C(q, q̇) q̇_r + g(q) = Y θ: three regressors, as in
        `coriolis_times` (H q̈_r + g = Y(q, 0, q̈_r); C q̇_r by polarization)."""
        zero = jnp.zeros_like(q)
        velocity = lambda u: self.regressor(q, u, zero, gravity=False)
        return self.regressor(q, zero, qdd_r) + 0.25 * (velocity(qd + qd_r) - velocity(qd - qd_r))

    # -- the Structure interface (matrix form) --------------------------------------------------
    def inertia(self, q, p):
        return self.mass_matrix(q, self.theta(p))

    def coriolis(self, q, qd, p):
        theta = self.theta(p)
        return jax.jacfwd(lambda v: self.coriolis_times(q, qd, v, theta))(jnp.zeros_like(qd))

    def rigid_torque(self, q, qd, qdd, p):
        """H(q) q̈ + C(q, q̇) q̇ + g(q) + diag(Ia) q̈: gravity is part of `rigid` for serial chains."""
        return self.rnea(q, qd, qdd, self.theta(p))

    def solve(self, H, r):
        return jnp.linalg.solve(H, r)

    def violations(self, p):
        """Physical consistency: each link's pseudo-inertia [[½ tr(I) 1 − I, h], [hᵀ, m]] positive
        semidefinite (a mass distribution exists), armatures non-negative."""
        theta, n, out = np.asarray(self.theta(p), dtype=float), self.n_joints, []
        for j in range(n):
            t = theta[10 * j : 10 * j + 10]
            I = np.asarray(_inertia_tensor(t))
            J = np.block([[0.5 * np.trace(I) * np.eye(3) - I, t[1:4, None]], [t[None, 1:4], t[:1, None]]])
            if np.linalg.eigvalsh(J)[0] < -1e-9 * max(1.0, np.abs(J).max()):
                out.append(
                    f"link {j + 1}: no mass distribution has these inertial parameters "
                    "(pseudo-inertia not positive semidefinite)"
                )
        out += [
            f"Ia{j + 1} = {theta[10 * n + j]:.4g}: an armature must be non-negative"
            for j in range(n)
            if theta[10 * n + j] < 0
        ]
        return out

    # -- the simulator's joint-tuple form (pose, shift, moved: `_Configuration`) ------------
    def mass(self, pose, p):
        return Dense(self.mass_matrix(jnp.stack(pose), self.theta(p)))

    def bias(self, pose, qd, p):
        """C(q, q̇) q̇ + g(q): gravity is part of `rigid` for serial chains."""
        q = jnp.stack(pose)
        tau = self.rnea(q, jnp.stack(qd), jnp.zeros_like(q), self.theta(p))
        return tuple(tau[i] for i in range(self.n_joints))

    def _closed_form(self, H):
        return Dense(H)

    # -- what the rest of manus asks of a structure ---------------------------------------------
    @property
    def urdf_file(self):
        return self.source

    def nominal(self, effect):
        """The joints' `<dynamics>`: damping for `viscous`, friction for `coulomb`."""
        return {"viscous": self.damping, "coulomb": self.friction}.get(effect, ())

    def nominal_joint_inertias(self):
        H = np.asarray(self.mass_matrix(jnp.zeros(self.n_joints), jnp.asarray(self.defaults)))
        return np.diag(H)

    # -- identification --------------------------------------------------------------------
    def base(self) -> SerialBase:
        """This chain in its base parameters (`base_parameters`), the form identification uses."""
        return _base_of(self)

    def pseudo(self) -> SerialPseudo:
        """This chain in pseudo-inertia coordinates (`manus.plants.pseudo_inertia`), the form adaptive
        control uses: its links are consistent exactly when each pseudo-inertia is PSD."""
        return SerialPseudo(self)

    def identified_form(self):
        """In base parameters (`base`): the combinations the torque determines."""
        return self.base()

    def adaptive_form(self):
        """In pseudo-inertia coordinates (`pseudo`), where the projection keeps every link consistent."""
        return self.pseudo()


# -- base parameters -----------------------------------------------------------------------------------


class BaseParameters(NamedTuple):
    """The identifiable combinations of a structure's standard parameters.

    `columns` (r,): the standard parameters kept (their regressor columns are the base
    regressor); `K` (r, P): θ_base = K θ (K = [I  β] in column-pivoted order: each dependent
    column of the regressor is a combination β of the kept ones); `names` (r,): each base
    parameter written out, e.g. `Izz2 + 0.1·m3`.
    """

    columns: np.ndarray
    K: np.ndarray
    names: tuple[str, ...]

    def regressor(self, Y):
        """The base regressor: the kept columns of Y (..., P)."""
        return Y[..., self.columns]

    def values(self, theta):
        """The base parameters (r,) of the standard parameters θ (P,)."""
        return self.K @ np.asarray(theta)


def base_parameters(serial: Serial, samples: int = 200, seed: int = 0, tol: float = 1e-8) -> BaseParameters:
    """Gautier's numerical method: stack the regressor over `samples` random states (q uniform on
    [−π, π] (±0.5 m for prismatic joints), q̇ and q̈ standard normal), QR with column pivoting;
    columns whose |R_kk| falls below `tol`·|R_00| are combinations of the kept ones.
    """
    import scipy.linalg

    n, rng = serial.n_joints, np.random.default_rng(seed)
    span = np.where(serial.prismatic, 0.5, np.pi)
    q = rng.uniform(-span, span, (samples, n))
    qd, qdd = rng.standard_normal((2, samples, n))
    with jax.enable_x64(True):  # the numerical rank needs float64
        Y = np.asarray(_regressors(serial, q, qd, qdd)).reshape(samples * n, -1)
    _, R, perm = scipy.linalg.qr(Y, mode="economic", pivoting=True)  # pyright: ignore[reportAssignmentType]
    diagonal = np.abs(np.diag(R))
    r = int(np.sum(diagonal > tol * diagonal[0]))
    beta = scipy.linalg.solve_triangular(R[:r, :r], R[:r, r:])
    beta[np.abs(beta) < 1e-10] = 0.0
    kept, dependent = np.sort(perm[:r]), perm[r:]
    order = np.argsort(perm[:r])  # rows of beta in the order of the kept columns
    K = np.zeros((r, Y.shape[1]))
    K[np.arange(r), kept] = 1.0
    K[:, dependent] = beta[order]
    names = serial.rigid_names
    labels = tuple(
        " ".join(
            [
                names[c],
                *(
                    f"{'+' if b > 0 else '−'} {abs(b):.4g}·{names[d]}"
                    for b, d in ((K[i, d], d) for d in np.sort(dependent))
                    if b != 0
                ),
            ]
        )
        for i, c in enumerate(kept)
    )
    return BaseParameters(kept, K, labels)


_BASES: dict[tuple, BaseParameters] = {}


def _base_of(serial: Serial) -> SerialBase:
    """`SerialBase` of a chain; its base parameters computed once per geometry (they do not depend
    on the parameter values)."""
    key = (
        serial.joint_names,
        serial.prismatic,
        *(np.asarray(x, float).tobytes() for x in (serial.rotation, serial.translation, serial.axis, serial.gravity)),
    )
    if key not in _BASES:
        _BASES[key] = base_parameters(serial)
    b = _BASES[key]
    standard = serial.rigid_names
    names = tuple(standard[c] + ("R" if " " in label else "") for c, label in zip(b.columns, b.names, strict=True))
    return SerialBase(
        serial=serial,
        n_joints=serial.n_joints,
        columns=tuple(int(c) for c in b.columns),
        base_names=names,
        written=b.names,
        K=b.K,
        transmission=serial.transmission,
    )


class Reparametrized(_Configuration):
    """A chain in other rigid parameters than the standard ones (base parameters, pseudo-inertia
    entries): `self.serial` and `self.standard(p)`, the standard vector of its parameters, give
    H, C and the simulator's joint-tuple form."""

    if TYPE_CHECKING:  # each form's own field
        serial: Serial

    @abc.abstractmethod
    def standard(self, p: dict) -> Array:
        """The standard parameter vector (11 n,) of these parameters `p` (by name)."""

    def inertia(self, q, p):
        return self.serial.mass_matrix(q, self.standard(p))

    def coriolis(self, q, qd, p):
        theta = self.standard(p)
        return jax.jacfwd(lambda v: self.serial.coriolis_times(q, qd, v, theta))(jnp.zeros_like(qd))

    def solve(self, H, r):
        return jnp.linalg.solve(H, r)

    @property
    def prismatic(self) -> tuple[bool, ...]:
        return self.serial.prismatic

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.serial.joint_names

    @property
    def standard_form(self):
        return self.serial

    @property
    def urdf_file(self):
        return self.serial.source

    def nominal(self, effect):
        return self.serial.nominal(effect)

    def nominal_joint_inertias(self):
        return self.serial.nominal_joint_inertias()

    # -- the simulator's joint-tuple form (see `Serial`) -----------------------------------------
    def mass(self, pose, p):
        return Dense(self.serial.mass_matrix(jnp.stack(pose), self.standard(p)))

    def bias(self, pose, qd, p):
        q = jnp.stack(pose)
        tau = self.serial.rnea(q, jnp.stack(qd), jnp.zeros_like(q), self.standard(p))
        return tuple(tau[i] for i in range(self.n_joints))

    def _closed_form(self, H):
        return Dense(H)


class SerialBase(Reparametrized):
    """A serial chain in its base parameters: what inverse-dynamics identification can know.

    Its rigid parameters are θ_b = K θ (`BaseParameters`, Gautier's numerical QR), each named after
    the standard parameter it keeps, with `R` appended when others are regrouped into it (Khalil
    and Gautier's convention: `Izz2R` = Izz2 + 0.1·m3 + ...); `combinations` (the field `written`)
    writes each one out. The rigid torque is the base regressor (the kept columns of
    `Serial.regressor`) times θ_b. H(q), C(q, q̇), g(q) and the simulator's joint-tuple form take
    the standard parameters with θ_b in the kept places and zeros elsewhere: every standard θ with
    the same K θ gives the same torque in every state, so they are the base parameters' own (which
    is also why a fitted set can be simulated: the instruments of IDIM-IV).
    """

    serial: Serial
    n_joints: int = eqx.field(static=True)
    columns: tuple[int, ...] = eqx.field(static=True)
    base_names: tuple[str, ...] = eqx.field(static=True)
    written: tuple[str, ...] = eqx.field(static=True)  # each base parameter written out (`combinations`)
    K: np.ndarray
    CHECK_STATES: ClassVar[int] = 64  # random configurations on which `violations` checks H(q) > 0

    @property
    def rigid_names(self):
        return self.base_names

    @property
    def combinations(self):
        return self.written

    @property
    def rigid_defaults(self):
        return tuple(float(v) for v in self.K @ np.asarray(self.serial.defaults))

    def values(self, theta) -> np.ndarray:
        """The base parameters (r,) of standard parameters θ (11 n,)."""
        return self.K @ np.asarray(theta, float)

    def coordinates_of(self, standard):
        """The base parameters K θ."""
        theta = np.array([float(standard[k]) for k in self.serial.rigid_names])
        return dict(zip(self.base_names, self.values(theta).tolist(), strict=True))

    def standard(self, p: dict) -> Array:
        """A standard parameter vector with these base parameters: θ_b in the kept places, zeros elsewhere."""
        theta_b = jnp.stack([jnp.asarray(p[k]) for k in self.base_names])
        return jnp.zeros(len(self.serial.rigid_names), theta_b.dtype).at[jnp.asarray(self.columns)].set(theta_b)

    def regressor(self, q: Vector, qd: Vector, qdd: Vector) -> Array:
        """The base regressor (n, r)."""
        return self.serial.regressor(q, qd, qdd)[:, jnp.asarray(self.columns)]

    # -- matrix form ---------------------------------------------------------------------------
    def rigid_torque(self, q, qd, qdd, p):
        theta_b = jnp.stack([jnp.asarray(p[k]) for k in self.base_names])
        return self.regressor(q, qd, qdd) @ theta_b

    @property
    def armatures(self) -> tuple[str, ...]:
        """The base parameters that are one joint's armature alone (`Ia3`; not a regrouped `Ia1R`,
        a combination that may be negative): each is non-negative on a physical robot."""
        return tuple(k for k, w in zip(self.base_names, self.written, strict=True) if k.startswith("Ia") and k == w)

    def violations(self, p, q=None):
        """Base parameters are combinations, so the pseudo-inertia of a link cannot be checked;
        what can: H(q) positive definite, at the configurations `q` (m, n) (default: `CHECK_STATES`
        random ones)."""
        where = "random configurations" if q is None else "recorded states"
        if q is None:
            span = np.where(self.serial.prismatic, 0.5, np.pi)
            q = np.random.default_rng(0).uniform(-span, span, (self.CHECK_STATES, self.n_joints))
        theta = np.zeros(len(self.serial.rigid_names))  # (`standard`'s vector, without a dispatch per entry)
        theta[np.asarray(self.columns)] = [float(p[k]) for k in self.base_names]
        with jax.enable_x64(True):
            H = np.asarray(_mass_matrices(self.serial, jnp.asarray(q), jnp.asarray(theta)))
        low = np.linalg.eigvalsh(H)[:, 0]
        bad = int(np.sum(~(low > 0)))
        if not bad:
            return []
        return [
            f"the base parameters give an inertia matrix H(q) that is not positive definite (in {bad} of "
            f"{len(q)} {where}, smallest eigenvalue {low.min():.3g}): no physical robot has them"
        ]


class SerialPseudo(Reparametrized):
    """A serial chain in pseudo-inertia coordinates (`manus.plants.pseudo_inertia`): the form adaptive
    control uses (`Serial.pseudo()`), its links consistent exactly when each pseudo-inertia is PSD."""

    serial: Serial
    n_joints: int = eqx.field(static=True)
    scale: tuple[float, ...] = eqx.field(static=True)  # each link's radius of gyration ℓ [m] (1 for a massless link)

    def __init__(self, serial: Serial):
        self.serial = serial
        self.n_joints = serial.n_joints
        self.transmission = serial.transmission
        d = np.asarray(serial.defaults, float)
        scale = []
        for i in range(serial.n_joints):
            e = entries_of(d[10 * i : 10 * i + 10])
            scale.append(float(np.sqrt(max(e[4] + e[5] + e[6], 0.0) / e[0])) if e[0] > 0 else 1.0)
        self.scale = tuple(x if x > 0 else 1.0 for x in scale)

    @property
    def rigid_names(self):
        links = tuple(f"J{i + 1}{e}" for i in range(self.n_joints) for e in ENTRIES)
        return links + tuple(f"Ia{i + 1}" for i in range(self.n_joints))

    @property
    def rigid_defaults(self):
        d = np.asarray(self.serial.defaults, float)
        n = self.n_joints
        links = [entries_of(d[10 * i : 10 * i + 10]) for i in range(n)]
        return tuple(float(x) for x in np.concatenate([*links, d[10 * n :]]))

    def rigid_gains(self, gain: float) -> dict[str, float]:
        """Adaptation gains for which the Γ⁻¹ metric on a link's entries is the Frobenius norm of
        its scaled pseudo-inertia (times ℓ²/`gain`): gain/ℓ² on m, gain/2 on h, gain ℓ² on Σ's
        diagonal and gain ℓ²/2 off it (`gain` where the first moments are); `gain` on the armatures."""
        out = {}
        for i, l in enumerate(self.scale):
            for e in ENTRIES:
                power = -2 if e == "m" else (0 if e.startswith("h") else 2)
                out[f"J{i + 1}{e}"] = gain * l**power * (0.5 if e in OFF_DIAGONAL else 1.0)
            out[f"Ia{i + 1}"] = gain
        return out

    def admissible(self):
        """Each link's scaled pseudo-inertia positive semidefinite, each armature ≥ 0."""
        n = self.n_joints
        return Admissible(
            nonnegative=tuple(f"Ia{i + 1}" for i in range(n)),
            links=tuple((tuple(f"J{i + 1}{e}" for e in ENTRIES), self.scale[i]) for i in range(n)),
        )

    def coordinates_of(self, standard):
        """The pseudo-inertia entries and the armatures."""
        s, n = self.serial, self.n_joints
        phi = np.array([float(standard[k]) for k in s.rigid_names])
        links = [entries_of(phi[10 * i : 10 * i + 10]) for i in range(n)]
        return dict(zip(self.rigid_names, np.concatenate([*links, phi[10 * n :]]).tolist(), strict=True))

    def standard(self, p: dict) -> jax.Array:
        """The standard parameter vector (11 n,) of these parameters."""
        n = self.n_joints
        links = [standard_of(jnp.stack([jnp.asarray(p[f"J{i + 1}{e}"]) for e in ENTRIES])) for i in range(n)]
        return jnp.concatenate([*links, jnp.stack([jnp.asarray(p[f"Ia{i + 1}"]) for i in range(n)])])

    # -- matrix form ---------------------------------------------------------------------------
    def rigid_torque(self, q, qd, qdd, p):
        return self.serial.rnea(q, qd, qdd, self.standard(p))

    def violations(self, p):
        standard = np.asarray(self.standard({k: float(p[k]) for k in self.rigid_names}))
        return self.serial.violations(dict(zip(self.serial.rigid_names, standard, strict=True)))
