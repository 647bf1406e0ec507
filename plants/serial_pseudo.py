"""A serial chain in pseudo-inertia coordinates: the form adaptive control uses.

Each link's ten inertial parameters are the entries of its pseudo-inertia (Wensing, Kim and
Slotine 2017), the second moments of its mass distribution in the link frame:

    J = [[Σ, h], [hᵀ, m]],   Σ = ∫ r rᵀ dm = ½ tr(I) 𝟙 − I,   h = ∫ r dm = m c,

named `J{i}m`, `J{i}hx`, `J{i}hy`, `J{i}hz`, `J{i}xx`, `J{i}yy`, `J{i}zz`, `J{i}xy`, `J{i}xz`,
`J{i}yz`, then one armature per joint, `Ia{i}`. The map to the standard parameters (m, m c, I about
the link origin) is linear (I = tr(Σ) 𝟙 − Σ), so the torque stays linear in them, and the links are
physically consistent exactly when every J is positive semidefinite. In these coordinates the
closest consistent point in the Frobenius norm of J is J with its negative eigenvalues set to zero:
the projection `manus.adaptive.projection.Projection` applies for a chain (one 4x4 eigen-
decomposition per link per tick), exact in the metric of the adaptation gains when those follow
the pattern `rigid_gains` gives (the off-diagonal entries appear twice in J: half the gain).

Each link's J is scaled by its radius of gyration ℓ (the URDF's: √(tr Σ / m)) as diag(1/ℓ, 1/ℓ,
1/ℓ, 1) J diag(1/ℓ, 1/ℓ, 1/ℓ, 1) before the Frobenius norm, so that mass, first and second moments
weigh alike; `rigid_gains` carries the same scaling.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from manus.plants.serial import GRAVITY_IN_RIGID, Serial, _Reparametrized

ENTRIES = ("m", "hx", "hy", "hz", "xx", "yy", "zz", "xy", "xz", "yz")
OFF_DIAGONAL = ("hx", "hy", "hz", "xy", "xz", "yz")


def standard_of(j: np.ndarray) -> np.ndarray:
    """One link's standard parameters (m, mx, my, mz, Ixx, Ixy, Ixz, Iyy, Iyz, Izz) from its
    pseudo-inertia entries (in the order of `ENTRIES`); numpy or JAX arrays."""
    xp = jnp if isinstance(j, jax.Array) else np
    m, hx, hy, hz, sxx, syy, szz, sxy, sxz, syz = (j[k] for k in range(10))
    return xp.stack([m, hx, hy, hz, syy + szz, -sxy, -sxz, sxx + szz, -syz, sxx + syy])


def entries_of(phi: np.ndarray) -> np.ndarray:
    """The inverse of `standard_of`: Σ = ½ tr(I) 𝟙 − I."""
    m, mx, my, mz, ixx, ixy, ixz, iyy, iyz, izz = (float(x) for x in phi)
    half = 0.5 * (ixx + iyy + izz)
    return np.array([m, mx, my, mz, half - ixx, half - iyy, half - izz, -ixy, -ixz, -iyz])


def matrix(j) -> jax.Array:
    """The 4x4 pseudo-inertia of one link's entries."""
    m, hx, hy, hz, sxx, syy, szz, sxy, sxz, syz = (j[k] for k in range(10))
    return jnp.array([[sxx, sxy, sxz, hx], [sxy, syy, syz, hy], [sxz, syz, szz, hz], [hx, hy, hz, m]])


def entries_of_matrix(J) -> jax.Array:
    return jnp.stack([J[3, 3], J[0, 3], J[1, 3], J[2, 3], J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]])


class SerialPseudo(_Reparametrized):
    """A serial chain in pseudo-inertia coordinates (module docstring). `serial.pseudo()`."""

    name: ClassVar[str] = "urdf"
    rigid_gravity: ClassVar[str] = GRAVITY_IN_RIGID
    serial: Serial
    n_joints: int = eqx.field(static=True)
    scale: tuple[float, ...] = eqx.field(static=True)  # each link's radius of gyration ℓ [m] (1 for a massless link)

    def __init__(self, serial: Serial):
        self.serial = serial
        self.n_joints = serial.n_joints
        d = np.asarray(serial.defaults, float)
        scale = []
        for i in range(serial.n_joints):
            e = entries_of(d[10 * i:10 * i + 10])
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
        links = [entries_of(d[10 * i:10 * i + 10]) for i in range(n)]
        return tuple(float(x) for x in np.concatenate([*links, d[10 * n:]]))

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

    def values(self, standard: dict) -> dict[str, float]:
        """These coordinates of standard parameters given by name (the chain's `rigid_names`; a
        simulated plant's truth): the pseudo-inertia entries and the armatures."""
        s, n = self.serial, self.n_joints
        phi = np.array([float(standard[k]) for k in s.rigid_names])
        links = [entries_of(phi[10 * i:10 * i + 10]) for i in range(n)]
        return dict(zip(self.rigid_names, np.concatenate([*links, phi[10 * n:]]).tolist()))

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
        return self.serial.violations(dict(zip(self.serial.rigid_names, standard)))
