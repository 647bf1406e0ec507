"""Pseudo-inertia coordinates of a link: the form adaptive control gives a serial chain
(`manus.plants.serial.SerialPseudo`).

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
the pattern `SerialPseudo.rigid_gains` gives (the off-diagonal entries appear twice in J: half the
gain).

Each link's J is scaled by its radius of gyration ℓ (the URDF's: √(tr Σ / m)) as diag(1/ℓ, 1/ℓ,
1/ℓ, 1) J diag(1/ℓ, 1/ℓ, 1/ℓ, 1) before the Frobenius norm, so that mass, first and second moments
weigh alike; `rigid_gains` carries the same scaling.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

ENTRIES = ("m", "hx", "hy", "hz", "xx", "yy", "zz", "xy", "xz", "yz")
OFF_DIAGONAL = ("hx", "hy", "hz", "xy", "xz", "yz")


def standard_of(j: np.ndarray | jax.Array) -> np.ndarray | jax.Array:
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
