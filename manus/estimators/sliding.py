"""Levant's robust exact differentiator (`levant`), implicitly discretized so that it does not chatter.

The first-order sliding-mode differentiator of A. Levant, "Robust exact differentiation via
sliding mode technique", Automatica 34(3):379–384, 1998 (gains of A. Levant, "Higher-order
sliding modes, differentiation and output-feedback control", Int. J. Control 76(9–10), 2003):

    ż₀ = −k₁ L^½ ⌈z₀ − f⌋^½ + z₁,    ż₁ = −k₂ L ⌈z₀ − f⌋⁰,     k₁ = 1.5, k₂ = 1.1

(⌈x⌋^p = |x|^p sgn x; ⌈x⌋⁰ the set-valued sign). For a signal f whose second derivative is bounded
by L it converges in finite time to z₀ = f, z₁ = ḟ exactly; with noise of size ε the error is of
order √(L ε). L [position/s²] is the knob: the largest acceleration it must follow.

Discretized with the explicit Euler method it chatters: z₁ jumps by ±T k₂ L every sample in the
sliding mode. This is the implicit (backward) Euler discretization instead, with the measurement
of the new sample (B. Brogliato, A. Polyakov, D. Efimov, "The implicit discretization of the
supertwisting sliding-mode control algorithm", IEEE Trans. Autom. Control 65(8):3707–3713, 2020;
M. R. Mojallizadeh, B. Brogliato, V. Acary, "Time-discretizations of differentiators: design of
implicit algorithms and comparative analysis", Int. J. Robust Nonlinear Control 31(16), 2021):

    z₀⁺ = z₀ + T(−k₁ L^½ ⌈e⌋^½ + z₁⁺),   z₁⁺ = z₁ − T k₂ L s,   s ∈ Sgn(e),   e = z₀⁺ − f_k

The inclusion has one solution in closed form. With w = z₀ + T z₁ − f_k and c = T² k₂ L:
s = clip(w / c, −1, 1), and |e| = r² where r ≥ 0 solves r² + T k₁ L^½ r = max(|w| − c, 0),
e = sgn(w) r². Inside the band |w| ≤ c the differentiator is exactly on its sliding set (e = 0) and
its output moves smoothly; it never overshoots the set, so there is nothing to chatter.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
from jax import Array

from manus.estimators.base import Estimate, Estimator

K1, K2 = 1.5, 1.1  # Levant (2003): λ₀ = 1.5, λ₁ = 1.1 for the first-order differentiator


class LevantState(NamedTuple):
    z0: Array  # position estimate (n,)
    z1: Array  # velocity estimate (n,)


def implicit_step(z0, z1, f, dt, L, k1=K1, k2=K2):
    """One implicit Euler step of the differentiator: (z₀⁺, z₁⁺, s)."""
    w = z0 + dt * z1 - f
    c = dt * dt * k2 * L
    s = jnp.clip(w / c, -1.0, 1.0)
    b = dt * k1 * jnp.sqrt(L)
    m = jnp.maximum(jnp.abs(w) - c, 0.0)
    r = 2 * m / (b + jnp.sqrt(b * b + 4 * m))  # the positive root of r² + b r − m, without cancellation
    return f + jnp.sign(w) * r * r, z1 - dt * k2 * L * s, s


class Levant(Estimator):
    """The implicitly discretized Levant differentiator; `lipschitz` = L [position/s²]."""

    dt: float = eqx.field(static=True)
    lipschitz: Array

    def __init__(self, dt: float = 1e-3, lipschitz: float = 50.0):
        if not lipschitz > 0:
            raise ValueError(f"the Lipschitz constant L must be positive, got {lipschitz}")
        self.dt = float(dt)
        self.lipschitz = jnp.asarray(float(lipschitz))

    def init(self, q0):
        q0 = jnp.asarray(q0, float)
        return LevantState(q0, jnp.zeros_like(q0))

    def step(self, state, q, tau=None):
        z0, z1, _ = implicit_step(state.z0, state.z1, q, self.dt, self.lipschitz)
        return LevantState(z0, z1), Estimate(z0, z1)
