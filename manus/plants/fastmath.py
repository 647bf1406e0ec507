"""sin, cos and sign in forms that XLA vectorizes well on the CPU.

XLA evaluates float64 `jnp.sin`/`jnp.cos` one element at a time on the CPU; written as range
reduction plus polynomial kernels (multiplies, adds, rounding, selects) they vectorize, about 4×
faster under `vmap` (docs/performance.md). Every sin and cos of the physics
(structures, effects) comes from here, so the simulator, the regressors and the tests agree.

- Range reduction (Cody–Waite): k = round(x / (π/2)), r = x − k·P1 − k·P2 − k·P3 with π/2 split
  into parts short enough that k·P1 and k·P2 are exact; |r| ≤ π/4. Accurate to about one unit in
  the last place of 1 (2e-16 absolute in float64) for |x| < 2²⁰·π/2 ≈ 1.6e6 rad (float32: for
  |x| < 2¹²·π/2 ≈ 6400 rad); beyond that the error grows with |x|.
- Kernels on |r| ≤ π/4: the Taylor series, cut where the next term is below a sixteenth of the
  dtype's epsilon (degree 17 for sin and 16 for cos in float64).
- Derivatives are exact (`custom_jvp`: d sin = cos dx), not the polynomial's.
"""

from __future__ import annotations

import math
from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

EXACT_BELOW = 2.0**20 * math.pi / 2  # rad: float64 sin and cos exact to rounding below this |x| (above)

_PI = Fraction("3.14159265358979323846264338327950288419716939937510582097494459230781640628620899")
_HALF_PI = _PI / 2


def _round_bits(x: Fraction, bits: int) -> Fraction:
    """x rounded to `bits` significant bits."""
    e = math.floor(math.log2(abs(x)))
    scale = Fraction(2) ** (bits - 1 - e)
    return Fraction(round(x * scale)) / scale


def _split_half_pi(short_bits: int, mantissa_bits: int) -> tuple[float, float, float]:
    """π/2 ≈ P1 + P2 + P3, P1 and P2 of `short_bits` significant bits (so k·P is exact for
    k < 2^(mantissa_bits − short_bits)), P3 the rest rounded to the dtype."""
    p1 = _round_bits(_HALF_PI, short_bits)
    p2 = _round_bits(_HALF_PI - p1, short_bits)
    p3 = _round_bits(_HALF_PI - p1 - p2, mantissa_bits)
    return float(p1), float(p2), float(p3)


def _terms(first_power: int, sign: int, eps: float) -> tuple[float, ...]:
    """Taylor coefficients sign·(−1)^i / (first_power + 2i)!, up to where the next term on
    |r| ≤ π/4 is below eps/16."""
    out, power = [], first_power
    while True:
        out.append(sign * (-1) ** len(out) / math.factorial(power))
        power += 2
        if (math.pi / 4) ** power / math.factorial(power) < eps / 16:
            return tuple(out)


class _Consts:
    def __init__(self, dtype):
        info = np.finfo(dtype)
        mant = info.nmant + 1
        self.half_pi = _split_half_pi(mant - (20 if mant > 24 else 12), mant)
        self.sin = _terms(3, -1, float(info.eps))  # sin r = r + r·z·Σ sin[i] z^i,  z = r²
        self.cos = _terms(4, 1, float(info.eps))  # cos r = 1 − z/2 + z²·Σ cos[i] z^i


_CONSTS = {np.dtype(np.float64): _Consts(np.float64), np.dtype(np.float32): _Consts(np.float32)}


def _consts(x: Array) -> _Consts:
    return _CONSTS.get(np.dtype(x.dtype), _CONSTS[np.dtype(np.float64)])


def _horner(z, coefs):
    acc = coefs[-1]
    for c in coefs[-2::-1]:
        acc = c + z * acc
    return acc


def _float(x) -> Array:
    x = jnp.asarray(x)
    return x if jnp.issubdtype(x.dtype, jnp.floating) else x.astype(float)


def kernel_sincos(r: Array) -> tuple[Array, Array]:
    """(sin r, cos r) for |r| ≤ π/4, no range reduction (accurate to an ulp there)."""
    r = _float(r)
    k = _consts(r)
    z = r * r
    s = r + r * z * _horner(z, k.sin)
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + z * z * _horner(z, k.cos))  # recovers the rounding of 1 − z/2
    return s, c


@jax.custom_jvp
def sincos(x: Array) -> tuple[Array, Array]:
    """(sin x, cos x), evaluated with one shared range reduction."""
    x = _float(x)
    p1, p2, p3 = _consts(x).half_pi
    k = jnp.round(x * (2 / math.pi))
    s, c = kernel_sincos(((x - k * p1) - k * p2) - k * p3)
    quadrant = k - 4.0 * jnp.floor(0.25 * k)  # k mod 4 ∈ {0, 1, 2, 3}, in floating point
    odd = (quadrant == 1.0) | (quadrant == 3.0)
    s, c = jnp.where(odd, c, s), jnp.where(odd, s, c)
    return jnp.where(quadrant >= 2.0, -s, s), jnp.where((quadrant == 1.0) | (quadrant == 2.0), -c, c)


@sincos.defjvp
def _sincos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    s, c = sincos(x)
    return (s, c), (c * dx, -s * dx)


def sin(x: Array) -> Array:
    return sincos(x)[0]


def cos(x: Array) -> Array:
    return sincos(x)[1]


def sign(x: Array) -> Array:
    """`jnp.sign` (±1, ±0 for ±0, NaN for NaN, zero derivative) as compares and selects: XLA
    lowers `jnp.sign` of float64 to nine AVX2 instructions, these are four."""
    x = _float(x)
    return jnp.where(x > 0, 1.0, jnp.where(x < 0, -1.0, jax.lax.stop_gradient(x))).astype(x.dtype)
