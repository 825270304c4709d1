"""``envs_jax.trig``: the float32 polynomials against float64 numpy (error in float32 ulps of the true value),
float32 arrays under ``trig.SMALL`` elements and float64 inputs through XLA's own functions unchanged, and the
size that chooses between them taken over the whole batch under ``vmap``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_jax import trig

ULPS = 3  # largest error allowed, in ulps of the float32 nearest the true value


def ulps(got, want):
    """Error of float32 ``got`` against float64 ``want`` in units of the last place of ``want`` in float32."""
    want32 = want.astype(np.float32)
    spacing = np.spacing(np.maximum(np.abs(want32), np.finfo(np.float32).tiny)).astype(np.float64)
    return np.abs(got.astype(np.float64) - want) / spacing


def tiled(x):
    """``x`` repeated up to at least ``trig.SMALL`` elements, so that the polynomials evaluate it (the first
    ``len(x)`` entries are ``x``)."""
    x = np.asarray(x)
    return np.tile(x, (-(-trig.SMALL // len(x)),) + (1,) * (x.ndim - 1))


def inputs(low, high, n=200_001, seed=0):
    x = np.concatenate([np.linspace(low, high, n), np.random.default_rng(seed).uniform(low, high, n)])
    return x.astype(np.float32)


@pytest.mark.parametrize("name, low, high", [("sin", -100.0, 100.0), ("cos", -100.0, 100.0), ("tan", -1.5, 1.5),
                                             ("arctan", -50.0, 50.0), ("arcsin", -1.0, 1.0)])
def test_float32_within_a_few_ulps(name, low, high):
    x = inputs(low, high)
    got = np.asarray(jax.jit(getattr(trig, name))(jnp.asarray(x)))
    want = getattr(np, name)(x.astype(np.float64))
    err = ulps(got, want)
    assert err.max() <= ULPS, (name, float(err.max()), float(x[np.argmax(err)]))
    assert got.dtype == np.float32


def test_tan_near_its_poles_and_small_arguments_relative():
    x = np.concatenate([inputs(1.5, 1.57, 20_001), inputs(-1e-3, 1e-3, 20_001), np.float32([0, -0.0, 1e-30])])
    got = np.asarray(jax.jit(trig.tan)(jnp.asarray(x)))
    assert ulps(got, np.tan(x.astype(np.float64))).max() <= ULPS
    assert np.signbit(got[-2]) and got[-1] == np.float32(1e-30)
    assert not np.signbit(got[-3])


def test_arctan2_every_quadrant_and_the_axes():
    rng = np.random.default_rng(1)
    y = np.concatenate([rng.normal(0, 10, 400_000), rng.uniform(-1e-3, 1e-3, 1000)]).astype(np.float32)
    x = np.concatenate([rng.normal(0, 10, 400_000), rng.uniform(-1e3, 1e3, 1000)]).astype(np.float32)
    got = np.asarray(jax.jit(trig.arctan2)(jnp.asarray(y), jnp.asarray(x)))
    err = ulps(got, np.arctan2(y.astype(np.float64), x.astype(np.float64)))
    assert err.max() <= ULPS, float(err.max())
    axes = np.float32([[0, 1], [0, -1], [1, 0], [-1, 0], [0, 0], [-0.0, 0], [0, -0.0], [-0.0, -0.0], [3, 3], [-2, -2]])
    got = np.asarray(trig.arctan2(jnp.asarray(tiled(axes)[:, 0]), jnp.asarray(tiled(axes)[:, 1])))[:len(axes)]
    want = np.arctan2(axes[:, 0].astype(np.float64), axes[:, 1].astype(np.float64)).astype(np.float32)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(np.signbit(got), np.signbit(want))


def test_sin_cos_is_sin_and_cos_and_quadrants_are_exact():
    x = tiled(np.float32([0, np.pi / 2, np.pi, -np.pi / 2, 3 * np.pi / 2, 2 * np.pi, 1e-20]))
    s, c = jax.jit(trig.sin_cos)(jnp.asarray(x))
    np.testing.assert_array_equal(np.asarray(s), np.asarray(jax.jit(trig.sin)(jnp.asarray(x))))
    np.testing.assert_array_equal(np.asarray(c), np.asarray(jax.jit(trig.cos)(jnp.asarray(x))))
    np.testing.assert_allclose(np.asarray(s), np.sin(x.astype(np.float64)), rtol=0, atol=2e-7)
    np.testing.assert_allclose(np.asarray(c), np.cos(x.astype(np.float64)), rtol=0, atol=2e-7)


@pytest.mark.parametrize("size", [1, 64])
def test_nan_propagates(size):
    nan, one = jnp.full(size, jnp.nan, jnp.float32), jnp.ones(size, jnp.float32)
    for f in (trig.sin, trig.cos, trig.tan, trig.arctan, trig.arcsin):
        assert np.isnan(f(nan)).all(), f
    assert np.isnan(trig.arctan2(nan, one)).all() and np.isnan(trig.arctan2(one, nan)).all()


FUNCTIONS = {"sin": (-100.0, 100.0), "cos": (-100.0, 100.0), "tan": (-1.5, 1.5), "arctan": (-50.0, 50.0),
             "arcsin": (-1.0, 1.0)}


@pytest.mark.parametrize("name", FUNCTIONS)
def test_small_arrays_are_xlas_own_and_a_batch_is_sized_whole(name):
    """Under ``trig.SMALL`` elements a float32 call is XLA's own function; a batch of small rows under ``vmap``
    (nested or not) gives the results of the same values as one array, the polynomials' from that size on."""
    f = getattr(trig, name)
    x = np.random.default_rng(3).uniform(*FUNCTIONS[name], 4 * trig.SMALL).astype(np.float32)
    small = jnp.asarray(x[:trig.SMALL - 1])
    np.testing.assert_array_equal(np.asarray(jax.jit(f)(small)), np.asarray(jax.jit(getattr(jnp, name))(small)))
    whole = np.asarray(jax.jit(f)(jnp.asarray(x)))
    assert ulps(whole, getattr(np, name)(x.astype(np.float64))).max() <= ULPS
    rows = jax.jit(jax.vmap(f))(jnp.asarray(x).reshape(-1, 2))
    nested = jax.jit(jax.vmap(jax.vmap(f)))(jnp.asarray(x).reshape(8, -1, 1))
    np.testing.assert_array_equal(np.asarray(rows).reshape(-1), whole)
    np.testing.assert_array_equal(np.asarray(nested).reshape(-1), whole)


def test_arctan2_batch_with_a_shared_argument_is_sized_whole():
    y = np.random.default_rng(4).normal(size=(trig.SMALL, 2)).astype(np.float32)
    x = np.float32([0.5, -2.0])
    got = jax.jit(jax.vmap(trig.arctan2, in_axes=(0, None)))(jnp.asarray(y), jnp.asarray(x))
    np.testing.assert_array_equal(np.asarray(got), np.asarray(jax.jit(trig.arctan2)(jnp.asarray(y), jnp.asarray(x))))


def test_float64_is_xlas_own(x64):
    x = jnp.asarray(np.random.default_rng(2).uniform(-0.99, 0.99, 1000))
    for name in ("sin", "cos", "tan", "arctan", "arcsin"):
        np.testing.assert_array_equal(np.asarray(getattr(trig, name)(x)), np.asarray(getattr(jnp, name)(x)))
    np.testing.assert_array_equal(np.asarray(trig.arctan2(x, x[::-1])), np.asarray(jnp.arctan2(x, x[::-1])))
