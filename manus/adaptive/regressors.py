"""Regressors for adaptive control: Y with Y θ = the torque a model asks for along a *reference*
motion, built from the same effect definitions as the simulator and the fit (`manus.plants.effects`).

Slotine–Li form (`form="slotine-li"`, the default). With the reference velocity and acceleration

    q̇_r = q̇_d − Λ q̃,   q̈_r = q̈_d − Λ q̃̇,   q̃ = q − q_d,

the rigid columns are those of

    Y_rigid(q, q̇, q̇_r, q̈_r) a = H(q) q̈_r + C(q, q̇) q̇_r

with C the structure's Coriolis matrix, written so that Ḣ − 2C is skew-symmetric: the property
the Lyapunov proof of Slotine and Li (1987) rests on. For MANUS-2 (absolute angles,
c = cos(q2 − q1), s = sin(q2 − q1)):

    Y = [[q̈r1,  c q̈r2 − s q̇2 q̇r2,  0   ],
         [0,    c q̈r1 + s q̇1 q̇r1,  q̈r2]]

Thesis form (`form="thesis"`): the Y matrix after eq. C.5, which puts the reference velocity in
both slots of the Coriolis term, H(q) q̈_r + C(q, q̇_r) q̇_r (terms −s q̇r2² and s q̇r1²). It is
what the thesis ran; Ḣ − 2C skew-symmetry does not cover it, so the textbook proof does not apply.
(Eq. C.1–C.2 print q̇2 and q̇1 without the square; eq. 3.2 and the physics have it.)

Friction and load effects (viscous, coulomb, stribeck, asymmetry, offset, gravity, cogging) add
their columns evaluated at (q, q̇_r), like every other term of Y: the standard choice that keeps
the proof. The closed loop then carries the extra term
−(F(q̇) − F(q̇_r)) θ_F on the right of H ṡ + (C + K_D) s = Y ã, and for friction that is
non-decreasing in velocity with non-negative coefficients (viscous, coulomb, and the boundary
layer below) sᵀ(F(q̇) − F(q̇_r)) ≥ 0 because s = q̇ − q̇_r: it only dissipates. Stribeck friction
falls with speed and `asymmetry` is not monotone on its own: with them the proof needs the
friction to stay monotone in total (Fc ≥ |dFc|, b ≥ |db|), which the law does not enforce.
Position-only effects (offset, gravity, cogging) are exact at q.

Coulomb-type effects use a boundary layer: sgn(v) becomes sat(v/φ), φ = `boundary` [rad/s or
m/s] (default 0.01), so the command stays continuous when q̇_r crosses zero; φ = 0 gives the sign.

Delay and compliance are not linear in parameters and have no columns: a model that names them
is refused.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
from jax import Array

from manus.plants.effects import Model
from manus.plants.errors import ModelError

FORMS = ("slotine-li", "thesis")
DEFAULT_BOUNDARY = 0.01  # φ [rad/s]: under 1 % of the complex trajectory's peak speed


class Regressor(eqx.Module):
    """Y(q, q̇, q̇_r, q̈_r) of shape (n, P) for `model`; P = len(model.names).

    Arguments are per joint, shape (n,): the measured position q, the estimated velocity q̇
    (used only by the Slotine–Li Coriolis term), and the reference velocity and acceleration.
    """

    model: Model
    form: str = eqx.field(static=True)
    boundary: float = eqx.field(static=True)

    def __init__(self, model: Model, form: str = "slotine-li", boundary: float = DEFAULT_BOUNDARY):
        if not isinstance(model, Model):
            raise ModelError(f"a regressor needs a manus.plants.effects.Model, not {type(model).__name__}")
        if form not in FORMS:
            raise ModelError(f"unknown regressor form {form!r}: expected one of {', '.join(FORMS)}")
        if not model.has("rigid"):
            raise ModelError(f"model {model.spec!r} has no 'rigid' effect: adaptive control needs the inertia")
        other = [e.spec for e in model.effects if not e.linear]
        if other:
            raise ModelError(
                f"effect(s) {', '.join(other)} are not linear in parameters: leave them out of an adaptive model"
            )
        if not boundary >= 0:
            raise ModelError(f"boundary layer must be >= 0 rad/s, got {boundary}")
        self.model = model
        self.form = form
        self.boundary = float(boundary)

    @property
    def names(self) -> tuple[str, ...]:
        return self.model.names

    @property
    def n_joints(self) -> int:
        return self.model.n_joints

    def torque(self, q, qd, qd_r, qdd_r, theta) -> Array:
        """Y θ without forming Y: the torque of the parameters `theta` (P,) along the reference."""
        s, p = self.model.structure, self.model.unvector(theta)
        total = jnp.zeros(s.n_joints, jnp.result_type(qd_r, theta))
        for e in self.model.effects:
            if e.inertial and self.form == "slotine-li":
                total = total + s.inertia(q, p) @ qdd_r + s.coriolis(q, qd, p) @ qd_r
                if s.rigid_gravity:  # a serial chain's rigid effect holds gravity, g(q)
                    zero = jnp.zeros_like(qdd_r)
                    total = total + s.rigid_torque(q, zero, zero, p)
            else:
                total = total + self.model.effect_torque(e, q, qd_r, qdd_r, p, self.boundary)
        return total

    def __call__(self, q, qd, qd_r, qdd_r) -> Array:
        """Y, shape (n, P): ∂(Y θ)/∂θ, exact because every column is linear in θ. In the Slotine–Li
        form the rigid columns of a structure that writes them out (`Structure.slotine_li_columns`:
        MANUS-2's, the matrix in the module docstring) are its per-joint scalars, no 2×2 products,
        which under `vmap` become a tiny matrix product per trial."""
        theta0 = jnp.zeros(len(self.names), jnp.result_type(qd_r, float))
        s = self.model.structure
        columns = s.slotine_li_columns(q, qd, qd_r, qdd_r) if self.form == "slotine-li" else None
        if columns is None:
            return jax.jacfwd(lambda th: self.torque(q, qd, qd_r, qdd_r, th))(theta0)
        if len(self.model.effects) > 1:  # the other effects' columns (elementwise in the joints)

            def rest(th):
                p = self.model.unvector(th)
                return sum(
                    self.model.effect_torque(e, q, qd_r, qdd_r, p, self.boundary)
                    for e in self.model.effects
                    if not e.inertial
                )

            Yo = jax.jacfwd(rest)(theta0)
            columns.update({k: (Yo[0, i], Yo[1, i]) for i, k in enumerate(self.names) if k not in columns})
        return jnp.stack([jnp.stack(columns[k]) for k in self.names], axis=1)
