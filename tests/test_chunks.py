"""``envs_jax.in_chunks``: a batched call in chunks gives ``vmap``'s results, and the compiled program chunks."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from envs_jax.chunks import in_chunks


def _fn(x, tree, scale):
    """A pytree in and out, a reduction over the row, a shared argument."""
    y = jnp.sin(x) * scale + tree["b"].astype(x.dtype)
    return {"sum": jnp.sum(y * tree["w"]), "rows": y}, tree["b"] & (x > 0)


# below, at, and above the chunk (with and without a remainder); x64, where a batch's width cannot change a rounding
@pytest.mark.parametrize("size", [3, 8, 21, 32])
def test_equals_vmap(size, x64):
    rng = np.random.default_rng(size)
    x = jnp.asarray(rng.normal(size=(size, 5)))
    tree = {"w": jnp.asarray(rng.normal(size=5)), "b": jnp.asarray(rng.random((size, 5)) < 0.5)}
    scale = jnp.float64(1.5)
    in_axes = (0, {"w": None, "b": 0}, None)
    want = jax.jit(jax.vmap(_fn, in_axes=in_axes))(x, tree, scale)
    got = jax.jit(jax.vmap(in_chunks(_fn, 8), in_axes=in_axes))(x, tree, scale)
    for a, b in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(got)):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # unbatched: the function itself; nested vmap: still vmap's results
    one = jax.jit(in_chunks(_fn, 8))(x[0], {"w": tree["w"], "b": tree["b"][0]}, scale)
    np.testing.assert_array_equal(np.asarray(one[0]["rows"]), np.asarray(want[0]["rows"][0]))
    nested = jax.vmap(jax.vmap(in_chunks(_fn, 2), in_axes=(0, {"w": None, "b": 0}, None)),
                      in_axes=(0, {"w": None, "b": 0}, None))
    got2 = jax.jit(nested)(x[None], {"w": tree["w"], "b": tree["b"][None]}, scale)
    np.testing.assert_array_equal(np.asarray(got2[0]["rows"][0]), np.asarray(want[0]["rows"]))


def test_compiled_program_runs_in_chunks():
    """Above the chunk the CPU program loops over chunks of the given width; at or below it, it does not."""
    f = jax.vmap(in_chunks(lambda x: jnp.cumsum(x) * 2.0, 4))
    big = jax.jit(f).lower(jnp.ones((16, 6))).compile().as_text()
    small = jax.jit(f).lower(jnp.ones((4, 6))).compile().as_text()
    assert "while" in big and "f32[4,6]" in big
    assert "while" not in small
    assert in_chunks(jnp.sin, None) is jnp.sin
    with pytest.raises(ValueError, match="rows must be a positive"):
        in_chunks(jnp.sin, 0)


def test_highway_batch_chunk_option():
    assert envs_jax.make("highway-v0").task.batch_chunk == 32  # 51 slots: 2,048 // 51 = 40 -> 32
    assert envs_jax.make("highway-fast-v0").task.batch_chunk == 64  # 21 slots
    assert envs_jax.make("highway-v0", vehicles_count=100).task.batch_chunk == 16
    assert envs_jax.make("highway-v0", batch_chunk=None).task.batch_chunk is None
    assert envs_jax.make("highway-v0", {"batch_chunk": 5}).task.batch_chunk == 5
    for bad in (0, -3, 2.5, True, "32"):
        with pytest.raises(ValueError, match="batch_chunk must be None .* or an integer >= 1"):
            envs_jax.make("highway-v0", batch_chunk=bad)


def test_chunked_highway_step_matches_the_whole_batch(x64):
    """A small highway task stepped under ``vmap`` in chunks of 3 (two chunks and a remainder of 2 for 8
    environments) equals the same task stepped as one batch: every state leaf, observation, reward, cost and flag
    after each of a few random steps. Exact for the discrete fields; the floats to the last bits, as between any
    two batch widths (XLA:CPU vectorises a batch's bulk and its tail differently; 3 environments of the whole batch
    stepped alone differ from the 8 by as much)."""
    small = dict(vehicles_count=6, lanes_count=2)
    chunked = envs_jax.make("highway-fast-v0", batch_chunk=3, **small)
    whole = envs_jax.make("highway-fast-v0", batch_chunk=None, **small)
    n = 8
    p = chunked.default_params
    keys = jax.random.split(jax.random.key(3), n)
    _, state = jax.vmap(chunked.reset, in_axes=(0, None))(keys, p)
    # compiled once each (ahead of time), both to count the loops and to step
    compiled = lambda env: jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None))).lower(
        keys, state, jnp.zeros((n, 1), jnp.int32), p).compile()
    step_c, step_w = compiled(chunked), compiled(whole)
    assert step_c.as_text().count(" while(") > step_w.as_text().count(" while(")  # the chunk loop
    sc = sw = state
    for t in range(4):
        k = jax.random.split(jax.random.key(10 + t), n)
        a = jax.random.randint(jax.random.key(20 + t), (n, 1), 0, 5, jnp.int32)
        out_c, out_w = step_c(k, sc, a, p), step_w(k, sw, a, p)
        for u, v in zip(jax.tree_util.tree_leaves(out_c), jax.tree_util.tree_leaves(out_w)):
            u, v = np.asarray(u), np.asarray(v)
            if np.issubdtype(u.dtype, np.floating):
                np.testing.assert_allclose(u, v, rtol=1e-12, atol=1e-12)
            else:
                np.testing.assert_array_equal(u, v)
        sc, sw = out_c[1], out_w[1]
