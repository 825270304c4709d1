"""Lagrange multipliers (p21, p22b/p22d): projected dual ascent and the authors' non-decreasing hinge rule."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl.lagrangian import Lagrangian


def _dual_ref(lam, costs, d, lr, lam_max):
    """Plain-numpy projected dual ascent over a sequence of cost batches."""
    out = []
    for c in costs:
        lam = np.clip(lam + lr * (c.mean(axis=0) - d), 0.0, lam_max)
        out.append(lam.copy())
    return np.array(out)


def test_dual_rises_above_threshold_and_falls_below():
    lag = Lagrangian(threshold=(1.0, 2.0), lr=0.1, lam_max=100.0, lam_init=0.5)
    lam = lag.init()
    above = jnp.array([[3.0, 2.5], [1.0, 3.5]])  # means (2, 3) > (1, 2)
    up = lag.update(lam, above)
    np.testing.assert_allclose(up, [0.5 + 0.1 * 1.0, 0.5 + 0.1 * 1.0], rtol=1e-6)
    below = jnp.array([[0.0, 1.0], [0.5, 1.5]])  # means (0.25, 1.25) < (1, 2)
    down = lag.update(up, below)
    np.testing.assert_allclose(down, np.asarray(up) - 0.1 * np.array([0.75, 0.75]), rtol=1e-6)
    assert np.all(np.asarray(down) < np.asarray(up))


def test_dual_projection_at_zero_and_bound_over_a_sequence():
    rng = np.random.default_rng(0)
    d, lr, lam_max = np.array([1.0, 0.5]), 0.7, 2.0
    lag = Lagrangian(threshold=tuple(d), lr=lr, lam_max=lam_max)
    costs = [rng.normal(1.0, 3.0, size=(16, 2)).astype(np.float32) for _ in range(60)]
    ref = _dual_ref(np.zeros(2), costs, d, lr, lam_max)
    lam, got = lag.init(), []
    step = jax.jit(lag.update)
    for c in costs:
        lam = step(lam, c)
        got.append(np.asarray(lam))
    got = np.array(got)
    np.testing.assert_allclose(got, ref, rtol=1e-5, atol=1e-6)
    assert got.min() == 0.0 and got.max() == lam_max  # both projections were active in this sequence


def test_authors_rule_never_decreases_and_uses_the_hinge():
    rng = np.random.default_rng(1)
    d = np.array([1.0, 1.0])
    lag = Lagrangian(threshold=tuple(d), lr=0.05, lam_max=100.0, rule="authors")
    lam = lag.init()
    prev = np.asarray(lam)
    for _ in range(50):
        c = rng.normal(0.8, 1.0, size=(32, 2)).astype(np.float32)  # mostly below d: dual ascent would fall
        lam = lag.update(lam, c)
        expected = np.clip(prev + 0.05 * np.maximum(c - d, 0).mean(axis=0), 0, 100)
        np.testing.assert_allclose(lam, expected, rtol=1e-5, atol=1e-7)
        assert np.all(np.asarray(lam) >= prev)
        prev = np.asarray(lam)
    assert np.all(prev > 0)


def test_penalty_values_and_gradients():
    lam = jnp.array([2.0, 0.5])
    g = jnp.array([[3.0, 0.0], [0.5, 2.0]])
    dual = Lagrangian(threshold=(1.0, 1.0), rule="dual")
    hinge = Lagrangian(threshold=(1.0, 1.0), rule="authors")
    np.testing.assert_allclose(dual.penalty(lam, g), [[4.0, -0.5], [-1.0, 0.5]])
    np.testing.assert_allclose(hinge.penalty(lam, g), [[4.0, 0.0], [0.0, 0.5]])
    # d/dG = lam (dual) or lam * 1[G > d] (hinge); the penalty never moves lambda
    np.testing.assert_allclose(jax.grad(lambda x: dual.penalty(lam, x).sum())(g), [[2.0, 0.5], [2.0, 0.5]])
    np.testing.assert_allclose(jax.grad(lambda x: hinge.penalty(lam, x).sum())(g), [[2.0, 0.0], [0.0, 0.5]])
    np.testing.assert_allclose(jax.grad(lambda lam_: dual.penalty(lam_, g).sum())(lam), [0.0, 0.0])


def test_runs_in_x64(x64):
    lag = Lagrangian(threshold=(0.5,), lr=0.1)
    lam = lag.update(lag.init(), jnp.array([[1.0], [2.0]]))
    assert lam.dtype == jnp.float64
    np.testing.assert_allclose(lam, [0.1 * 1.0])


@pytest.mark.parametrize("kw, msg", [
    (dict(rule="pid"), "rule"), (dict(lr=-1.0), "learning rate"), (dict(lam_max=-1.0), "lam_max"),
    (dict(lam_init=5.0, lam_max=1.0), "initial multiplier"),
])
def test_bad_settings_raise(kw, msg):
    with pytest.raises(ValueError, match=msg):
        Lagrangian(threshold=(1.0, 1.0), **kw)
