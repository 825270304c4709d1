"""``envs_jax.materialize``: values pass unchanged, and XLA keeps the buffer it exists for."""

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.materialize import materialize


def test_values_unchanged_under_jit_and_vmap():
    rng = np.random.default_rng(0)
    tree = {"f": jnp.asarray(rng.normal(size=(3, 4, 5)), jnp.float32),
            "i": jnp.asarray(rng.integers(-9, 9, size=(3, 4)), jnp.int32),
            "b": jnp.asarray(rng.random((3, 4)) < 0.5),
            "nan": jnp.full((3, 4), jnp.nan)}
    for fn in (materialize, jax.jit(materialize), jax.vmap(materialize), jax.jit(jax.vmap(jax.vmap(materialize)))):
        out = fn(tree)
        for k in tree:
            assert out[k].dtype == tree[k].dtype and out[k].shape == tree[k].shape
            np.testing.assert_array_equal(np.asarray(out[k]), np.asarray(tree[k]))
    # unbatched leaves beside batched ones keep their shape under vmap
    out = jax.vmap(lambda x, y: materialize((x, y)), in_axes=(0, None))(tree["f"], tree["i"])
    np.testing.assert_array_equal(np.asarray(out[1]), np.asarray(jnp.broadcast_to(tree["i"], (3, 3, 4))))
    assert materialize(()) == ()


def test_compiler_keeps_the_buffer():
    """The point of the helper: the compiled program still holds the loop (a barrier would be gone on the CPU),
    so consumers read one buffer instead of each recomputing the producer."""
    def f(x):
        y = materialize(jnp.sin(x) * 2.0)
        return y[:, 0] + y[:, 1], jnp.sum(y * y)

    text = jax.jit(f).lower(jnp.ones((8, 4))).compile().as_text()
    assert "while" in text
    np.testing.assert_allclose(np.asarray(jax.jit(f)(jnp.ones((8, 4)))[1]), 8 * 4 * (2 * np.sin(1.0)) ** 2,
                               rtol=1e-6)
