"""Parameter projection: keep the estimates physically admissible without breaking the proof.

The admissible set Θ (the structure says which of its rigid parameters are admissible,
`Structure.admissible`):

- the inertia matrix stays positive definite with a margin, H(q) ⪰ ε I for every q. For MANUS-2,
  H(q) = [[a1, a2 c], [a2 c, a3]] with |c| ≤ 1, this holds for all q exactly when the 2×2 matrix
  M = [[a1, a2], [a2, a3]] satisfies M ⪰ ε I (the worst case is c² = 1): a convex cone, shifted.
  For single axes, M_i ≥ ε. For a serial chain in pseudo-inertia coordinates, each link's
  pseudo-inertia positive semidefinite and each armature ≥ 0 (`_onto_pseudo_inertias`).
- each effect's own lower bounds (`Effect.lower_bounds`): friction coefficients b (viscous), Fc
  (coulomb), dFs (stribeck) and a spring's k are non-negative; the other parameters (asymmetry,
  offset, gravity, cogging) are signed and left free.

After each gradient step the estimate is projected onto Θ in the metric of Γ⁻¹,
‖x‖² = Σ x_i² / γ_i. That metric matters: for a convex Θ holding the truth a, the projection P
satisfies ‖P(y) − a‖_Γ⁻¹ ≤ ‖y − a‖_Γ⁻¹, so the Lyapunov function ½ sᵀHs + ½ ãᵀΓ⁻¹ã of the
Slotine–Li proof never grows by projecting (a Euclidean projection with a non-scalar Γ could
make it grow). The composite law's least-squares gain P is not diagonal; there the metric is
diag(P)⁻¹: the estimates stay admissible, and the inequality holds only approximately.

The box constraints separate (Γ is diagonal). The cone is a second-order cone: in the coordinates
z = Γ^{-1/2} (u, v, w) of the metric, P = (z_u + z_w)/√2, M = (z_u − z_w)/√2, V = z_v, the set
{[[u, v], [v, w]] ⪰ 0} is {P ≥ √(M² + r V²)}, r = 2 γ_v/√(γ_u γ_w): an elliptic cone, projected on
in the Euclidean norm of z. A point (P₀, M₀, V₀) outside it with P₀ ≥ 0 lands on its boundary at

    M = M₀/(1 + μ),   V = V₀/(1 + r μ),   P = √(M² + r V²),   for the μ ∈ [0, 1] with
    F(μ) = P₀ / √(M² + r V²) − (1 − μ) = 0

(the stationarity conditions P = P₀/(1 − μ), M = M₀/(1 + μ), V = V₀/(1 + r μ) on P² = M² + r V²).
F is concave and increasing on [0, 1] (1/√(a⁻² + b⁻²) is concave in a, b > 0, here affine in μ),
so Newton's method from a point left of the root climbs to it monotonically; it starts from the
larger of the roots with M or V alone (both left of it) and takes `NEWTON_STEPS` steps, no branch:
machine precision for 1e-6 ≤ r ≤ 1e6 (and every iterate lies on the boundary: admissible even
unconverged). A point with P₀ < 0 goes through Moreau's decomposition, P_K(z) = z + P_K*(−z), onto
the dual cone K* = {P ≥ √(M² + V²/r)}, where −z has P ≥ 0 (inside K*, i.e. z in the polar cone:
the projection is the apex, 0). Everything is elementwise arithmetic with a fixed number of steps:
under `vmap` every quantity is a batch vector.

Only a point outside the cone needs any of it (inside, θ comes back bit for bit): one trial
branches on that, and a vmapped batch branches once on whether any of its trials is outside
(`jax.custom_batching.custom_vmap`), which in the convergence trials happens only in their first
few hundred ticks.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from manus.plants.effects import Model
from manus.plants.errors import ModelError
from manus.plants.pseudo_inertia import entries_of_matrix, matrix

NEWTON_STEPS = 10
_SQRT_HALF = math.sqrt(0.5)


def _onto_elliptic_cone(p0, m0, v0, r):
    """The Euclidean projection of (p0, m0, v0), p0 >= 0, onto {P ≥ √(M² + r V²)} (module docstring)."""
    am, av = jnp.abs(m0), jnp.sqrt(r) * jnp.abs(v0)
    tiny = jnp.finfo(jnp.result_type(p0, float)).tiny
    # the roots with M alone and with V alone: left of the root of both together
    mu = jnp.maximum(
        0.0, jnp.maximum((am - p0) / jnp.maximum(am + p0, tiny), (av - p0) / jnp.maximum(r * p0 + av, tiny))
    )

    def newton(_, mu):
        a, b = 1.0 / (1.0 + mu), 1.0 / (1.0 + r * mu)
        m, v = m0 * a, v0 * b
        rho2 = jnp.maximum(m * m + r * v * v, tiny)
        rho = jnp.sqrt(rho2)
        # F = p0/ρ − (1 − μ); dρ/dμ = −(m²/(1 + μ) + r² v²/(1 + r μ))/ρ
        f = p0 / rho - (1.0 - mu)
        df = 1.0 + p0 * (m * m * a + r * r * v * v * b) / (rho2 * rho)
        return mu - f / df

    mu = jax.lax.fori_loop(0, NEWTON_STEPS, newton, mu, unroll=True)
    m, v = m0 / (1.0 + mu), v0 / (1.0 + r * mu)
    inside = m0 * m0 + r * v0 * v0 <= p0 * p0
    return (jnp.where(inside, p0, jnp.sqrt(m * m + r * v * v)), jnp.where(inside, m0, m), jnp.where(inside, v0, v))


def project_psd2(u, v, w, g1, g2, g3):
    """The point of {[[u, v], [v, w]] ⪰ 0} closest to (u, v, w) in the metric diag(1/g)
    (module docstring); points inside come back unchanged."""
    s1, s2, s3 = jnp.sqrt(g1), jnp.sqrt(g2), jnp.sqrt(g3)
    zu, zw = u / s1, w / s3
    p0, m0, v0 = (zu + zw) * _SQRT_HALF, (zu - zw) * _SQRT_HALF, v / s2
    r = 2.0 * g2 / (s1 * s3)
    dual = p0 < 0  # Moreau: P_K(z) = z + P_K*(−z), K* the cone with 1/r
    sign = jnp.where(dual, -1.0, 1.0)
    p, m, n = _onto_elliptic_cone(sign * p0, sign * m0, sign * v0, jnp.where(dual, 1.0 / r, r))
    p, m, n = (jnp.where(dual, x0 + x, x) for x0, x in ((p0, p), (m0, m), (v0, n)))
    inside = (u >= 0) & (w >= 0) & (u * w >= v * v)
    return (
        jnp.where(inside, u, s1 * (p + m) * _SQRT_HALF),
        jnp.where(inside, v, s2 * n),
        jnp.where(inside, w, s3 * (p - m) * _SQRT_HALF),
    )


class Projection(eqx.Module):
    """θ ↦ the closest admissible θ in the Γ⁻¹ metric (see the module docstring)."""

    lower: Array  # (P,) lower bounds: 0 for friction, ε for axis inertias, −inf otherwise
    cone: tuple[int, ...] | None = eqx.field(static=True)  # indices of the cone's (u, v, w): manus2's a1, a2, a3
    min_inertia: float = eqx.field(static=True)  # ε [kg m²]
    # a serial chain in pseudo-inertia coordinates: per link, the indices of its 10 entries and ℓ
    links: tuple = eqx.field(static=True, default=())

    def __init__(self, model: Model, min_inertia: float = 1e-3):
        if not min_inertia >= 0:
            raise ModelError(f"min_inertia must be >= 0 kg m², got {min_inertia}")
        s, names = model.structure, model.names
        lower = np.full(len(names), -np.inf)
        bounds = [lo for e in model.effects if not e.inertial for lo in e.lower_bounds(s)]
        lower[[i for i, k in enumerate(names) if k not in s.rigid_names]] = bounds  # each effect's own rules
        admissible = s.admissible()  # the structure's own rules for its rigid parameters
        if admissible is None:
            raise ModelError(f"no admissible parameter set is known for structure {s.name!r}")
        self.links = tuple((tuple(names.index(k) for k in entries), scale) for entries, scale in admissible.links)
        if admissible.nonnegative:
            lower[[names.index(k) for k in admissible.nonnegative]] = 0.0
        if admissible.positive:
            lower[[names.index(k) for k in admissible.positive]] = min_inertia
        self.cone = None if admissible.cone is None else tuple(names.index(k) for k in admissible.cone)
        self.lower = jnp.asarray(lower)
        self.min_inertia = float(min_inertia)

    def __call__(self, theta: Array, gamma: Array | np.ndarray) -> Array:
        """The projection of θ (P,) in the metric of Γ⁻¹ = diag(1/gamma)."""
        theta = jnp.maximum(theta, self.lower)
        if self.links:
            return _onto_pseudo_inertias(theta, self.links)
        if self.cone is None:
            return theta
        cone, eps = self.cone, self.min_inertia
        outside = lambda t: _outside_cone(t, cone, eps)
        onto = lambda t, g: _onto_cone(t, g, cone, eps)
        keep = lambda t, g: t

        # Only a point outside the cone needs the projection (inside, θ comes back bit for bit):
        # one trial branches on it; under vmap, where a `cond` on a per-trial flag would become a
        # select of both sides, the batch branches once on whether any of its trials is outside,
        # which is rare after the first ticks (docs/performance.md)
        @jax.custom_batching.custom_vmap
        def onto_cone(theta, gamma):
            return jax.lax.cond(outside(theta), onto, keep, theta, gamma)

        @onto_cone.def_vmap
        def onto_cone_batched(axis_size, in_batched, theta, gamma):
            theta, gamma = (
                x if batched else jnp.broadcast_to(x, (axis_size,) + x.shape)
                for x, batched in zip((theta, gamma), in_batched, strict=True)
            )
            # entries first (the batch vectors contiguous, as the batch keeps them)
            theta, gamma = theta.T, gamma.T
            any_outside = jnp.any(outside(theta))
            theta = jax.lax.cond(any_outside, jax.vmap(onto, in_axes=-1, out_axes=-1), keep, theta, gamma)
            return theta.T, True

        return onto_cone(theta, gamma)


def _onto_pseudo_inertias(theta: Array, links: tuple) -> Array:
    """θ with each link's pseudo-inertia J made positive semidefinite: the eigenvalues of its scaled
    J' = S J S (S = diag(1/ℓ, 1/ℓ, 1/ℓ, 1)) below 0 set to 0, the closest point in the Frobenius
    norm of J', which is the Γ⁻¹ metric for gains in `SerialPseudo.rigid_gains`' pattern
    (`manus.plants.pseudo_inertia`). A link already consistent comes back bit for bit."""
    moved = {}
    for idx, scale in links:
        S = jnp.array([1 / scale, 1 / scale, 1 / scale, 1.0])
        J = matrix(theta[jnp.array(idx)])
        Js = J * S[:, None] * S[None, :]
        w, V = jnp.linalg.eigh(Js)
        fixed = (V * jnp.maximum(w, 0.0)) @ V.T / (S[:, None] * S[None, :])
        fixed = 0.5 * (fixed + fixed.T)
        new = jnp.where(w[0] < 0, entries_of_matrix(fixed), theta[jnp.array(idx)])
        moved.update({k: new[i] for i, k in enumerate(idx)})
    return jnp.stack([moved[m] if m in moved else theta[m] for m in range(theta.shape[-1])])


def _outside_cone(theta: Array, cone: tuple[int, ...], eps: float) -> Array:
    """Whether θ (P,) lies outside the inertia cone M ⪰ ε I (M from the entries `cone` of θ)."""
    i, j, k = cone
    u, v, w = theta[i] - eps, theta[j], theta[k] - eps
    return ~((u >= 0) & (w >= 0) & (u * w >= v * v))


def _onto_cone(theta: Array, gamma: Array, cone: tuple[int, ...], eps: float) -> Array:
    """θ with its inertias projected onto the cone; a point inside comes back bit for bit."""
    i, j, k = cone
    u, v, w = theta[i] - eps, theta[j], theta[k] - eps
    pu, pv, pw = project_psd2(u, v, w, gamma[i], gamma[j], gamma[k])
    moved = {i: pu + eps, j: pv, k: pw + eps}  # θ rebuilt from its entries: no scatter under vmap
    projected = jnp.stack([moved[m] if m in moved else theta[m] for m in range(theta.shape[-1])])
    return jnp.where(_outside_cone(theta, cone, eps), projected, theta)
