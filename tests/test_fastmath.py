"""float32 polynomial trigonometry against float64 numpy; float64 must be numpy's exactly."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_jax import fastmath as F


def _ulps(got, ref):
    got = np.asarray(got, np.float64)
    spacing = np.spacing(np.abs(ref).astype(np.float32)).astype(np.float64)
    return np.max(np.abs(got - ref) / spacing)


RNG = np.random.default_rng(0)
CASES = {
    "sin": (F.sin, np.sin, RNG.uniform(-200, 200, 50000)),
    "cos": (F.cos, np.cos, RNG.uniform(-200, 200, 50000)),
    "tan": (F.tan, np.tan, RNG.uniform(-1.5, 1.5, 50000)),
    "arctan": (F.arctan, np.arctan, RNG.standard_cauchy(50000)),
    "arcsin": (F.arcsin, np.arcsin, np.concatenate([RNG.uniform(-1, 1, 50000), [-1.0, 0.0, 1.0]])),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_float32_within_3_ulp(name):
    fast, ref, x = CASES[name]
    x32 = x.astype(np.float32)
    assert _ulps(jax.jit(fast)(x32), ref(x32.astype(np.float64))) <= 3.0


def test_arctan2_quadrants_and_axes():
    y = np.concatenate([RNG.normal(size=50000), [0, 0, 1, -1, 0]]).astype(np.float32)
    x = np.concatenate([RNG.normal(size=50000), [1, -1, 0, 0, 0]]).astype(np.float32)
    got = np.asarray(jax.jit(F.arctan2)(y, x), np.float64)
    ref = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    assert _ulps(got, ref) <= 3.0


def test_float64_is_numpy(x64):
    x = RNG.uniform(-3, 3, 1000)
    for fast, ref in [(F.sin, np.sin), (F.cos, np.cos), (F.arctan, np.arctan)]:
        got = np.asarray(fast(jnp.asarray(x)))
        np.testing.assert_allclose(got, ref(x), rtol=4e-16, atol=0)
