"""Replay buffer: FIFO wrap-around, uniform sampling from filled slots only, jit/vmap safety."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl import buffers


def _items(start, n):
    v = jnp.arange(start, start + n, dtype=jnp.float32)
    return {"x": v, "pair": jnp.stack([v, -v], axis=-1), "flag": (jnp.arange(start, start + n) % 2 == 0)}


def test_init_shapes_and_dtypes():
    st = buffers.init({"o": jnp.zeros((2, 8)), "a": jnp.zeros((2,), jnp.int32), "t": jnp.zeros((), bool)}, 7)
    assert st.capacity == 7
    assert st.data["o"].shape == (7, 2, 8) and st.data["a"].dtype == jnp.int32 and st.data["t"].dtype == bool
    assert int(st.size) == 0 and int(st.pos) == 0
    with pytest.raises(ValueError):
        buffers.init({"x": jnp.zeros(())}, 0)


def test_wrap_around_overwrites_oldest_in_order():
    st = buffers.init({"x": jnp.zeros(()), "pair": jnp.zeros((2,)), "flag": jnp.zeros((), bool)}, 5)
    st = buffers.add(st, _items(0, 3))  # slots 0,1,2
    assert int(st.size) == 3 and int(st.pos) == 3
    st = buffers.add(st, _items(3, 4))  # 3,4 -> slots 3,4; 5,6 wrap to slots 0,1
    assert int(st.size) == 5 and int(st.pos) == 2
    np.testing.assert_array_equal(st.data["x"], [5, 6, 2, 3, 4])
    np.testing.assert_array_equal(st.data["pair"][:, 1], [-5, -6, -2, -3, -4])
    np.testing.assert_array_equal(st.data["flag"], [False, True, True, False, True])
    st = buffers.add(st, _items(7, 1))
    np.testing.assert_array_equal(st.data["x"], [5, 6, 7, 3, 4])
    assert int(st.pos) == 3 and int(st.size) == 5


def test_add_more_than_capacity_keeps_the_last_items():
    st = buffers.init({"x": jnp.zeros(())}, 4)
    st = buffers.add(st, {"x": jnp.arange(1.0, 2.0)})  # pos 1
    st = buffers.add(st, {"x": jnp.arange(10.0, 20.0)})  # 10 items into 4 slots, starting at slot 1
    # sequential writes would leave the last four items 16..19 at slots (1+6..9) % 4 = 3, 0, 1, 2
    np.testing.assert_array_equal(st.data["x"], [17, 18, 19, 16])
    assert int(st.pos) == (1 + 10) % 4 and int(st.size) == 4


def test_sample_only_from_filled_slots_and_with_replacement():
    st = buffers.init({"x": jnp.zeros(())}, 100)
    st = buffers.add(st, {"x": jnp.arange(1.0, 4.0)})  # 3 of 100 slots filled (the others hold 0)
    x = np.asarray(buffers.sample(st, jax.random.PRNGKey(0), 3000)["x"])
    assert set(np.unique(x)) == {1.0, 2.0, 3.0}
    counts = np.bincount(x.astype(int))[1:]
    assert counts.min() > 850  # roughly uniform (expected 1000 each)
    assert bool(buffers.can_sample(st, 3)) and not bool(buffers.can_sample(st, 4))


def test_jit_and_vmap_over_seeds():
    def fill(key):
        st = buffers.init({"x": jnp.zeros(())}, 8)
        st = jax.lax.fori_loop(0, 11, lambda i, s: buffers.add(s, {"x": i[None].astype(jnp.float32)}), st)
        return st, buffers.sample(st, key, 5)

    st, batch = jax.jit(jax.vmap(fill))(jax.random.split(jax.random.PRNGKey(1), 3))
    assert st.data["x"].shape == (3, 8)
    np.testing.assert_array_equal(st.data["x"][0], [8, 9, 10, 3, 4, 5, 6, 7])
    assert np.all(np.asarray(batch["x"]) >= 3)
