"""``envs_jax.env.sparse_map``: the batched rule (pack masked rows, run, scatter back) against the dense truth,
and vmapped environments against the same environments stepped one by one (the unbatched ``cond`` path)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from envs_jax.env import sparse_map
from envs_jax.sparse import _select_bit, _words, batch_rows, grouped_rows, running_count


def _fn(x, y):
    return {"a": jnp.sin(x) * y[0] + jnp.sum(x), "b": (y * 2.0).astype(jnp.float32)}


@pytest.mark.parametrize("batch, rows, p", [(3, 2, 0.5), (40, 3, 0.9), (200, 3, 0.05), (200, 3, 1.0), (70, 1, 0.0)])
def test_batched_rule_equals_dense_where(batch, rows, p):
    """Batches smaller and larger than one chunk (capacity max(64, n/8)), none, few and all rows masked."""
    k1, k2, k3 = jax.random.split(jax.random.PRNGKey(batch * 7 + rows), 3)
    x = jax.random.normal(k1, (batch, rows, 4))
    y = jax.random.normal(k2, (batch, rows, 2))
    mask = jax.random.uniform(k3, (batch, rows)) < p
    got = jax.jit(jax.vmap(lambda m, a, b: sparse_map(_fn, m, a, b)))(mask, x, y)
    full = jax.vmap(jax.vmap(_fn))(x, y)
    for k in ("a", "b"):
        m = mask.reshape(mask.shape + (1,) * (full[k].ndim - 2))
        np.testing.assert_allclose(np.asarray(got[k]), np.asarray(jnp.where(m, full[k], 0)), rtol=1e-6, atol=1e-6)
    # unbatched (the cond path) and an unbatched argument inside a batched call
    one = jax.jit(lambda m, a, b: sparse_map(_fn, m, a, b))(mask[0], x[0], y[0])
    np.testing.assert_allclose(np.asarray(one["a"]), np.asarray(got["a"][0]), rtol=1e-6, atol=1e-6)
    shared = jax.jit(jax.vmap(lambda m, a: sparse_map(_fn, m, a, y[0]), in_axes=(0, 0)))(mask, x)
    ref = jax.vmap(jax.vmap(_fn, in_axes=(0, 0)), in_axes=(0, None))(x, y[0])
    m = mask.reshape(mask.shape + (1,) * (ref["a"].ndim - 2))
    np.testing.assert_allclose(np.asarray(shared["a"]), np.asarray(jnp.where(m, ref["a"], 0)), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("batch, p, min_rows", [(1, 0.3, 4), (3, 0.5, 4), (3, 0.5, 64), (200, 0.05, 4),
                                                 (200, 0.6, 4)])
def test_segment_maxima_equal_brute_force(batch, p, min_rows):
    """``segments``: each masked row's values go to its segments (-1: none); the maxima per segment against a loop
    over the rows, batched (every row in one chunk, several chunks), unbatched, and with a shared argument."""
    n_seg, k = 5, 12
    rng = np.random.default_rng(batch)
    segments = rng.integers(-1, n_seg, size=(k, 2))
    segments[0] = -1  # a row that feeds no segment

    def fn(x, i):
        v = jnp.floor(jnp.abs(x[0]) * 10).astype(jnp.int32) + i
        return x * 2.0, (jnp.stack([v, v + 1]), jnp.stack([x[1] > 0, x[1] <= 0]).astype(jnp.int32))

    x = jnp.asarray(rng.normal(size=(batch, k, 2)), jnp.float32)
    mask = jnp.asarray(rng.uniform(size=(batch, k)) < p)
    index = jnp.arange(k, dtype=jnp.int32)
    call = lambda m, a: sparse_map(fn, m, a, index, fraction=1 / 8, min_rows=min_rows, segments=segments,
                                   n_segments=n_seg)
    rows, (big, flag) = jax.jit(jax.vmap(call))(mask, x)
    xs, ms = np.asarray(x), np.asarray(mask)
    for e in range(batch):
        want_big, want_flag = np.zeros(n_seg, np.int64), np.zeros(n_seg, np.int64)
        for r in np.flatnonzero(ms[e]):
            v = int(np.floor(np.abs(xs[e, r, 0]) * 10)) + r
            for j, s in enumerate(segments[r]):
                if s >= 0:
                    want_big[s] = max(want_big[s], v + j)
                    want_flag[s] = max(want_flag[s], int((xs[e, r, 1] > 0) if j == 0 else (xs[e, r, 1] <= 0)))
        np.testing.assert_array_equal(np.asarray(big[e]), want_big)
        np.testing.assert_array_equal(np.asarray(flag[e]), want_flag)
        np.testing.assert_allclose(np.asarray(rows[e]), np.where(ms[e][:, None], xs[e] * 2, 0))
    one_rows, (one_big, one_flag) = jax.jit(call)(mask[0], x[0])  # unbatched: the cond path
    np.testing.assert_array_equal(np.asarray(one_big), np.asarray(big[0]))
    np.testing.assert_array_equal(np.asarray(one_flag), np.asarray(flag[0]))
    np.testing.assert_allclose(np.asarray(one_rows), np.asarray(rows[0]))
    for bad, n in ((segments[:5], n_seg), (segments, 3), (segments[:, 0], n_seg)):  # rows, range, shape
        with pytest.raises(ValueError, match="segments"):
            sparse_map(fn, mask[0], x[0], index, segments=bad, n_segments=n)


def test_nested_vmap_equals_dense():
    k1, k2 = jax.random.split(jax.random.PRNGKey(3))
    x = jax.random.normal(k1, (4, 30, 3, 4))
    mask = jax.random.uniform(k2, (4, 30, 3)) < 0.3
    y = jnp.ones((4, 30, 3, 2))
    got = jax.jit(jax.vmap(jax.vmap(lambda m, a, b: sparse_map(_fn, m, a, b))))(mask, x, y)
    full = jax.vmap(jax.vmap(jax.vmap(_fn)))(x, y)
    np.testing.assert_allclose(np.asarray(got["a"]), np.asarray(jnp.where(mask[..., None], full["a"], 0)),
                               rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("fraction", [1 / 32, 1 / 4, 1.0])
def test_chunk_fraction_equals_dense_where(fraction):
    """Any chunk capacity gives the dense result, with one chunk or many (up to 90% of the rows masked)."""
    for p in (0.02, 0.3, 0.9):
        k1, k2, k3 = jax.random.split(jax.random.PRNGKey(int(p * 100)), 3)
        x = jax.random.normal(k1, (500, 2, 4))
        y = jax.random.normal(k2, (500, 2, 2))
        mask = jax.random.uniform(k3, (500, 2)) < p
        got = jax.jit(jax.vmap(lambda m, a, b: sparse_map(_fn, m, a, b, fraction=fraction)))(mask, x, y)
        full = jax.vmap(jax.vmap(_fn))(x, y)
        np.testing.assert_allclose(np.asarray(got["a"]), np.asarray(jnp.where(mask[..., None], full["a"], 0)),
                                   rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("n", [1, 2, 31, 32, 33, 100, 4096, 5001])
def test_words_and_bit_select_find_every_masked_row(n):
    """The word packing and the bit select that locate the masked rows: every masked row is found once, from
    its rank in word order, by the same search the chunks use."""
    for p in (0.0, 0.05, 0.5, 1.0):
        m = np.random.default_rng(n).uniform(size=n) < p
        words = np.asarray(jax.jit(_words)(jnp.asarray(m))).astype(np.int64)
        n_words = words.shape[0]
        bits = (words[None, :] >> np.arange(32)[:, None]) & 1  # [32, W]
        want = np.zeros(32 * n_words, bool)
        want[:n] = m
        np.testing.assert_array_equal(bits.reshape(-1), want)  # bit i of word w is row i W + w
        counts = bits.sum(axis=0)
        word_of = np.repeat(np.arange(n_words), counts)  # the r-th masked row in word order
        within = np.concatenate([np.arange(c) for c in counts]) if counts.sum() else np.zeros(0, int)
        pos = np.asarray(jax.jit(_select_bit)(jnp.asarray(words[word_of].astype(np.uint32)),
                                              jnp.asarray(within, jnp.int32)))
        rows = pos * n_words + word_of
        np.testing.assert_array_equal(np.sort(rows), np.flatnonzero(m))


@pytest.mark.parametrize("n", [1, 5, 31, 32, 33, 51, 64, 100])
def test_running_count_equals_cumsum(n):
    """``running_count`` (the rank of each masked row in ``grouped_rows``) against numpy's cumulative sum, for empty,
    sparse, half and full masks, alone and under ``vmap``."""
    rng = np.random.default_rng(n)
    masks = np.stack([rng.uniform(size=n) < p for p in (0.0, 0.1, 0.5, 1.0)])
    want = np.cumsum(masks, axis=1)
    got = np.asarray(jax.jit(jax.vmap(running_count))(jnp.asarray(masks)))
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, want)
    for m, w in zip(masks, want):
        np.testing.assert_array_equal(np.asarray(jax.jit(running_count)(jnp.asarray(m))), w)


@pytest.mark.parametrize("name", ["merge", pytest.param("roundabout", marks=pytest.mark.slow),  # discrete and
                                  pytest.param("intersection", marks=pytest.mark.slow), "racetrack"])  # continuous
def test_vmapped_envs_equal_envs_stepped_one_by_one(name):
    """Crashes and lane ends happen in some envs of the batch and not in others: the batched rule must give every
    env exactly what the unbatched step gives it."""
    env = envs_jax.make(name)
    w = envs_jax.AutoResetWrapper(env)
    params = env.default_params
    n, T = 24, 40
    keys = jax.random.split(jax.random.PRNGKey(11), n)
    policy = envs_jax.wrappers.random_actions(env)

    def run(key):
        k0, k1 = jax.random.split(key)
        obs, st = w.reset(k0, params)

        def body(c, k):
            obs, st = c
            ka, ks = jax.random.split(k)
            obs, st, r, cost, done, info = w.step(ks, st, policy(ka, obs), params)
            return (obs, st), (st.env_state.x, st.env_state.y, st.env_state.crashed, st.env_state.lane, r, done)

        return jax.lax.scan(body, (obs, st), jax.random.split(k1, T))[1]

    batched = jax.jit(jax.vmap(run))(keys)
    single = jax.jit(run)
    for i in range(n):
        one = single(keys[i])
        for b, s in zip(batched, one):
            np.testing.assert_allclose(np.asarray(b[i]), np.asarray(s), rtol=1e-5, atol=1e-4)
    lane = np.asarray(batched[3])
    assert (np.diff(lane, axis=1) != 0).any()  # lane ends reached: the next-lane path ran in some envs
    if name == "merge":
        assert np.asarray(batched[2]).any()  # and crashes (the obstacle): the SAT path


@pytest.mark.parametrize("name", [pytest.param("intersection-v0", marks=pytest.mark.slow), "merge-v0"])
def test_reset_where_equals_the_dense_reset_where_done(name):
    """``reset_where`` (auto-reset wrappers) against ``where(done, reset(key), 0)`` on 200 envs (capacity 25): few
    done (one chunk), 60% done (several chunks), and (merge) unbatched with done and not done. Both batches share
    one program each way. The intersection reset (a warm-up simulation) compiles for about a minute: on demand."""
    from envs_jax.sparse import reset_where

    env = envs_jax.make(name)
    params = env.default_params
    dense = jax.vmap(lambda k, d: jax.tree_util.tree_map(lambda r: jnp.where(d, r, jnp.zeros_like(r)),
                                                         env.reset(k, params)))
    sparse = jax.vmap(lambda k, d: reset_where(env.reset, d, k, params))
    n = 200
    keys = jax.random.split(jax.random.key(n), n)
    sparse, dense = jax.jit(sparse), jax.jit(dense)
    for percent, chunks in ((8, 1), (60, 5)):
        done = jnp.arange(n) * 37 % 100 < percent  # scattered over the batch, deterministic
        assert -(-int(done.sum()) // 25) == chunks  # one chunk of rows, then several
        got, want = sparse(keys, done), dense(keys, done)
        for g, w in zip(jax.tree_util.tree_leaves(got), jax.tree_util.tree_leaves(want)):
            np.testing.assert_allclose(np.asarray(g, np.float64), np.asarray(w, np.float64), rtol=1e-6, atol=1e-6)
    if name != "merge-v0":  # the unbatched path (a cond) is the same for every task: one task checks it
        return
    key = jax.random.key(7)
    obs, _ = env.reset(key, params)
    one = jax.jit(lambda d: reset_where(env.reset, d, key, params))
    np.testing.assert_allclose(np.asarray(one(jnp.array(True))[0]), np.asarray(obs), rtol=1e-6, atol=1e-6)
    assert not np.any(np.asarray(one(jnp.array(False))[0]))


@pytest.mark.parametrize("size", [1, 3, 8, 20])
def test_grouped_rows_equals_dense_where(size):
    """Each environment's masked rows, ``size`` at a time (one group, several, or every row at once), give
    ``fn`` on every row where masked and zeros elsewhere, batched and unbatched; ``fn`` reads the whole
    environment (its closure), as the drivers' lane-change work does."""
    k1, k2 = jax.random.split(jax.random.PRNGKey(size))
    x = jax.random.normal(k1, (50, 12, 3))
    mask = jax.random.uniform(k2, (50, 12)) < jnp.linspace(0.0, 1.0, 50)[:, None]  # none ... every row masked

    def one_env(m, a):
        def fn(rows):
            return {"y": jnp.sin(a[rows]) * jnp.sum(a), "k": rows * 2}
        return grouped_rows(fn, m, size)

    got = jax.jit(jax.vmap(one_env))(mask, x)
    want_y = jnp.where(mask[..., None], jnp.sin(x) * jnp.sum(x, axis=(1, 2))[:, None, None], 0)
    want_k = jnp.where(mask, jnp.arange(12) * 2, 0)
    np.testing.assert_allclose(np.asarray(got["y"]), np.asarray(want_y), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(got["k"]), np.asarray(want_k))
    alone = jax.jit(one_env)(mask[30], x[30])
    np.testing.assert_allclose(np.asarray(alone["y"]), np.asarray(want_y[30]), rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("batch", [3, 50])
def test_batch_rows_equals_dense_where(batch):
    """The masked rows of a whole batch packed together (one chunk for 3 environments; several for 50, capacity
    64 of 600 rows) give ``fn`` on every masked row, reading its own environment whole, and zeros elsewhere;
    unbatched one row at a time; an environment argument shared by the batch (not batched) is read as such."""
    x = jax.random.normal(jax.random.PRNGKey(batch), (batch, 12, 3))
    spread = jnp.arange(batch * 12).reshape(batch, 12) * 37 % 100  # scattered, deterministic
    mask = spread < jnp.linspace(0, 100, batch)[:, None]  # none in the first environment ... every row in the last
    shared = jnp.arange(12.0)

    def one_env(m, a):
        def fn(row, env):
            return {"y": jnp.sin(env["a"][row]) * jnp.sum(env["a"]) + env["w"][row], "k": row * 2}
        return batch_rows(fn, m, {"a": a, "w": shared})

    got = jax.jit(jax.vmap(one_env))(mask, x)
    want_y = jnp.where(mask[..., None], jnp.sin(x) * jnp.sum(x, axis=(1, 2))[:, None, None] + shared[:, None], 0)
    want_k = jnp.where(mask, jnp.arange(12) * 2, 0)
    np.testing.assert_allclose(np.asarray(got["y"]), np.asarray(want_y), rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(np.asarray(got["k"]), np.asarray(want_k))
    assert int(mask.sum()) > 64 or batch == 3  # the large batch needs several chunks
    alone = jax.jit(one_env)(mask[-1], x[-1])
    np.testing.assert_allclose(np.asarray(alone["y"]), np.asarray(want_y[-1]), rtol=1e-6, atol=1e-6)
