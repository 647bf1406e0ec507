"""The vectorizable sin, cos and sign against numpy and jnp.sign."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from manus.plants import fastmath

RNG = np.random.default_rng(7)
SINCOS = jax.jit(fastmath.sincos)


@pytest.mark.parametrize("span", [1.0, 100.0, 1e4, 1.5e6])
def test_sin_and_cos_match_numpy_to_an_ulp_of_one(span):
    x = np.concatenate([RNG.uniform(-span, span, 20000), np.arange(-64, 65) * (math.pi / 4)])
    s, c = SINCOS(x)
    assert np.abs(np.asarray(s) - np.sin(x)).max() <= 2.3e-16
    assert np.abs(np.asarray(c) - np.cos(x)).max() <= 2.3e-16


def test_small_arguments_keep_their_relative_accuracy_and_specials_propagate():
    x = np.array([1e-300, -1e-20, 3e-9, np.nan, np.inf, -np.inf])
    s, c = map(np.asarray, SINCOS(x))
    np.testing.assert_allclose(s[:3], np.sin(x[:3]), rtol=1e-16, atol=0)
    assert np.all(c[:3] == 1.0)
    assert np.all(np.isnan(s[3:])) and np.all(np.isnan(c[3:]))


def test_float32_is_accurate_to_its_own_precision():
    x = RNG.uniform(-3000, 3000, 20000).astype(np.float32)
    s, c = SINCOS(jnp.asarray(x, jnp.float32))
    assert s.dtype == jnp.float32 and c.dtype == jnp.float32
    assert np.abs(np.asarray(s, float) - np.sin(x.astype(float))).max() < 2 * np.finfo(np.float32).eps
    assert np.abs(np.asarray(c, float) - np.cos(x.astype(float))).max() < 2 * np.finfo(np.float32).eps


def test_kernel_without_reduction_on_its_interval():
    r = np.linspace(-math.pi / 4, math.pi / 4, 10001)
    s, c = jax.jit(fastmath.kernel_sincos)(r)
    assert np.abs(np.asarray(s) - np.sin(r)).max() <= 1.2e-16
    assert np.abs(np.asarray(c) - np.cos(r)).max() <= 1.2e-16


def test_derivatives_are_the_exact_ones():
    x = RNG.uniform(-50, 50, 64)
    ds, dc, dds = jax.jit(
        jax.vmap(lambda x: (jax.grad(fastmath.sin)(x), jax.grad(fastmath.cos)(x), jax.grad(jax.grad(fastmath.sin))(x)))
    )(x)
    np.testing.assert_allclose(ds, np.cos(x), rtol=0, atol=2.3e-16)
    np.testing.assert_allclose(dc, -np.sin(x), rtol=0, atol=2.3e-16)
    np.testing.assert_allclose(dds, -np.sin(x), rtol=0, atol=2.3e-16)


def test_sign_is_jnp_sign_including_signed_zeros_nan_and_its_zero_derivative():
    x = jnp.array([-0.0, 0.0, np.nan, -np.inf, np.inf, 1e-300, -2.5, 3.0])
    ours, ref, slope = map(
        np.asarray, jax.jit(lambda x: (fastmath.sign(x), jnp.sign(x), jax.vmap(jax.grad(fastmath.sign))(x)))(x)
    )
    np.testing.assert_array_equal(ours, ref)
    np.testing.assert_array_equal(np.signbit(ours), np.signbit(ref))
    assert np.all(slope[[0, 1, 3, 4, 5, 6, 7]] == 0)
