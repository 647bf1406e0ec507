"""Parameter projection: keep the estimates physically admissible without breaking the proof.

The admissible set Θ:

- the inertia matrix stays positive definite with a margin, H(q) ⪰ ε I for every q. For MANUS-2,
  H(q) = [[a1, a2 c], [a2 c, a3]] with |c| ≤ 1, this holds for all q exactly when the 2×2 matrix
  M = [[a1, a2], [a2, a3]] satisfies M ⪰ ε I (the worst case is c² = 1): a convex cone, shifted.
  For single axes, M_i ≥ ε.
- friction coefficients are non-negative: b (viscous), Fc (coulomb), dFs (stribeck). The other
  parameters (asymmetry, offset, gravity, cogging) are signed and left free.

After each gradient step the estimate is projected onto Θ in the metric of Γ⁻¹,
‖x‖² = Σ x_i² / γ_i. That metric matters: for a convex Θ holding the truth a, the projection P
satisfies ‖P(y) − a‖_Γ⁻¹ ≤ ‖y − a‖_Γ⁻¹, so the Lyapunov function ½ sᵀHs + ½ ãᵀΓ⁻¹ã of the
Slotine–Li proof never grows by projecting (a Euclidean projection with a non-scalar Γ could
make it grow). The composite law's least-squares gain P is not diagonal; there the metric is
diag(P)⁻¹: the estimates stay admissible, and the inequality holds only approximately.

The box constraints separate (Γ is diagonal). The cone is done exactly: a point outside it is
projected onto its boundary, the rank-one matrices t n nᵀ with n = (cos φ, sin φ), t ≥ 0; for a
given φ the best t is closed-form, and φ is found by a grid over [0, π) refined by golden-section
search (to about 1e-9 rad).
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from manus.adaptive.regressors import owners
from manus.plants.effects import Model
from manus.plants.errors import ModelError
from manus.plants.structures import Axis, Manus2

NONNEGATIVE = ("viscous", "coulomb", "stribeck")
GRID = 32
GOLDEN_STEPS = 40
INV_PHI = (math.sqrt(5) - 1) / 2


def _ray(phi):
    c, s = jnp.cos(phi), jnp.sin(phi)
    return c * c, c * s, s * s


def project_psd2(u, v, w, g1, g2, g3):
    """The point of {[[u, v], [v, w]] ⪰ 0} closest to (u, v, w) in the metric diag(1/g)."""
    def fit(phi):
        r = _ray(phi)
        num = u * r[0] / g1 + v * r[1] / g2 + w * r[2] / g3
        den = r[0] ** 2 / g1 + r[1] ** 2 / g2 + r[2] ** 2 / g3
        return jnp.maximum(num, 0.0) ** 2 / den, jnp.maximum(num, 0.0) / den  # gain, best t

    phis = jnp.arange(GRID) * (jnp.pi / GRID)
    best = phis[jnp.argmax(jax.vmap(lambda p: fit(p)[0])(phis))]
    h = jnp.pi / GRID

    def golden(_, ab):
        a, b = ab
        c, d = b - INV_PHI * (b - a), a + INV_PHI * (b - a)
        left = fit(c)[0] >= fit(d)[0]
        return jnp.where(left, a, c), jnp.where(left, d, b)

    a, b = jax.lax.fori_loop(0, GOLDEN_STEPS, golden, (best - h, best + h))
    phi = 0.5 * (a + b)
    t = fit(phi)[1]
    r = _ray(phi)
    inside = (u >= 0) & (w >= 0) & (u * w >= v * v)
    return tuple(jnp.where(inside, x, t * ri) for x, ri in zip((u, v, w), r))


class Projection(eqx.Module):
    """θ ↦ the closest admissible θ in the Γ⁻¹ metric (see the module docstring)."""

    lower: Array  # (P,) lower bounds: 0 for friction, ε for axis inertias, −inf otherwise
    cone: tuple[int, int, int] | None = eqx.field(static=True)  # indices of a1, a2, a3 (manus2)
    min_inertia: float = eqx.field(static=True)  # ε [kg m²]

    def __init__(self, model: Model, min_inertia: float = 1e-3):
        if not min_inertia >= 0:
            raise ModelError(f"min_inertia must be >= 0 kg m², got {min_inertia}")
        s, names, who = model.structure, model.names, owners(model)
        lower = np.full(len(names), -np.inf)
        lower[[i for i, e in enumerate(who) if e in NONNEGATIVE]] = 0.0
        self.cone = None
        if isinstance(s, Manus2):
            self.cone = tuple(names.index(k) for k in s.rigid_names)
        elif isinstance(s, Axis):
            lower[[names.index(k) for k in s.rigid_names]] = min_inertia
        else:
            raise ModelError(f"no admissible parameter set is known for structure {s.name!r}")
        self.lower = jnp.asarray(lower)
        self.min_inertia = float(min_inertia)

    def __call__(self, theta: Array, gamma: Array) -> Array:
        """The projection of θ (P,) in the metric of Γ⁻¹ = diag(1/gamma)."""
        theta = jnp.maximum(theta, self.lower)
        if self.cone is None:
            return theta
        i, j, k = self.cone
        eps, g = self.min_inertia, gamma
        u, v, w = theta[i] - eps, theta[j], theta[k] - eps

        def onto_cone():
            pu, pv, pw = project_psd2(u, v, w, g[i], g[j], g[k])
            return theta.at[i].set(pu + eps).at[j].set(pv).at[k].set(pw + eps)

        # inside, the cone leaves θ as it is: the search (most of a real-time tick) runs only
        # when the estimate leaves it (under vmap `cond` becomes a select and both run)
        inside = (u >= 0) & (w >= 0) & (u * w >= v * v)
        return jax.lax.cond(inside, lambda: theta, onto_cone)
