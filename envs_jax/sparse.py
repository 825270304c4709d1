"""``sparse_map``: run per-row work only on the rows that need it, also under ``vmap``."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.materialize import materialize


class TableRows(NamedTuple):
    """A row argument of :func:`sparse_map` given as rows of a table: row ``k`` is ``table[index[k]]``.

    ``table`` holds one environment's rows (``[M, ...]``, e.g. every vehicle's pose) and ``index`` (``[k]``, ints)
    picks one per row (e.g. the first vehicle of each pair). Under ``vmap`` only the packed rows are gathered, so the
    ``[k, ...]`` argument (one pose per vehicle pair, per environment) is never built.
    """

    table: jax.Array
    index: jax.Array


def sparse_map(fn, mask, *args, fraction: float = 1 / 8, min_rows: int = 64, segments=None, n_segments: int = 0):
    """``fn`` applied to the rows ``k`` of ``args`` (leading axis) where ``mask[k]``; zeros elsewhere.

    For work that is needed only rarely but would otherwise run for every
    environment under ``vmap`` (a batched ``cond`` evaluates both branches): the
    separating-axis test of vehicles that pass the bounding-circle prefilter, the
    next-lane choice of a vehicle at the end of its lane. Without ``vmap`` it is a
    ``cond`` on ``any(mask)``. Under ``vmap`` (custom batching rule) the masked rows
    of the whole batch are packed into chunks of a fixed capacity (``fraction`` of the
    rows, at least ``min_rows``: about the share of rows expected to be masked; fewer where
    a row is a whole environment's work), ``fn`` runs on
    those only, and the results are scattered back; a ``while_loop`` over chunks
    keeps it exact whatever the number of masked rows. Rows are independent, so the
    result equals ``where(mask, vmap(fn)(*args), 0)`` up to XLA compiling ``fn``'s
    arithmetic differently (an ulp at most; tests/test_sparse_map.py). An argument may be
    a :class:`TableRows` (rows gathered from a table only where needed); an argument without
    the batch axis is shared by every environment and is not copied per environment.

    With ``segments`` (static ``[k, m]`` ints: the ``m`` segments of ``0 .. n_segments - 1`` each row contributes to,
    ``-1``: none), ``fn`` returns ``(row_output, values)``, ``values`` a pytree of ``[m]`` non-negative numbers, and
    the result is ``(row outputs, maxima)``: each leaf of ``maxima`` (``[n_segments]``) is the largest value that a
    masked row gives its segment, 0 where none does. The maxima are scattered from the packed rows, so a per-vehicle
    reduction over a pair table (a crash, the last impact) never reads the whole table.
    """
    vfn = jax.vmap(fn)
    is_table = tuple(isinstance(a, TableRows) for a in args)
    leaves = [x for a in args for x in ((a.table, a.index) if isinstance(a, TableRows) else (a,))]

    seg = None if segments is None else np.asarray(segments, np.int32)  # [k, m]: each row's segments (-1: none)
    if seg is not None and (seg.ndim != 2 or seg.shape[0] != jnp.shape(mask)[-1] or seg.size == 0
                            or seg.min() < -1 or seg.max() >= n_segments):
        raise ValueError(f"sparse_map: segments must be a [rows, m] integer array with one row per mask row "
                         f"({jnp.shape(mask)[-1]}) and values from -1 (none) to n_segments - 1 ({n_segments - 1}); "
                         f"got shape {seg.shape}" + (f", values {seg.min()}..{seg.max()}" if seg.size else ""))

    def unbatched(mask, *leaves):
        rows = [g[0][g[1]] if table else g for table, g in zip(is_table, _regroup(is_table, leaves))]
        if seg is None:
            return _all_rows(vfn, mask, *rows)
        return _all_rows(vfn, mask, *rows, targets=(jnp.asarray(np.where(seg >= 0, seg, n_segments)), n_segments))

    f = jax.custom_batching.custom_vmap(unbatched)

    @f.def_vmap
    def rule(axis_size, in_batched, mask, *leaves):
        k = mask.shape[-1]
        groups = _regroup(is_table, list(zip(leaves, in_batched[1:])))  # (leaf, batched) per leaf
        getters = [_table_getter(*g[0], *g[1], axis_size, k) if table else _row_getter(*g, axis_size, k)
                   for table, g in zip(is_table, groups)]
        targets = None
        if seg is not None:  # flat rows -> their segments over the batch, [rows, m] (out of range: none)
            total = axis_size * n_segments
            own = jnp.asarray(seg)

            def flat_segments(rows):
                s = own[rows % k]
                return jnp.where(s >= 0, (rows // k)[:, None] * n_segments + s, total)

            targets = (flat_segments, total)
        out = _packed(vfn, _flat_mask(mask, in_batched[0], axis_size), lambda rows: tuple(g(rows) for g in getters),
                      fraction, min_rows, targets)
        if seg is None:
            return _per_environment(out, axis_size, k)
        rows_out, seg_out = out
        rows_out, flags = _per_environment(rows_out, axis_size, k)
        seg_out, seg_flags = _per_environment(seg_out, axis_size, n_segments)
        return (rows_out, seg_out), (flags, seg_flags)

    return f(mask, *leaves)


def _flat_mask(mask, batched: bool, axis_size: int):
    """A batching rule's ``[k]`` row mask (per environment, or shared) as one flat ``[axis_size k]`` mask."""
    k = mask.shape[-1]
    return (mask if batched else jnp.broadcast_to(mask, (axis_size, k))).reshape(axis_size * k)


def _per_environment(out, axis_size: int, k: int):
    """Results of the flat rows (``[axis_size k, ...]``) back to ``[axis_size, k, ...]``, with the rule's
    batched flags."""
    out = jax.tree_util.tree_map(lambda o: o.reshape((axis_size, k) + o.shape[1:]), out)
    return out, jax.tree_util.tree_map(lambda _: True, out)


def _regroup(is_table, items):
    """``sparse_map``'s flat leaves back into one item per argument: a pair (table, index) for a TableRows."""
    it = iter(items)
    return [(next(it), next(it)) if table else next(it) for table in is_table]


def _row_getter(arg, batched, axis_size: int, k: int):
    """Rows (flat indices over the batch) of a row argument, a pytree of ``[E, k, ...]`` or shared ``[k, ...]``."""
    n = axis_size * k

    def leaf(a, b):
        return (lambda rows: a.reshape((n,) + a.shape[2:])[rows]) if b else (lambda rows: a[rows % k])

    getters = jax.tree_util.tree_map(leaf, arg, batched)
    return lambda rows: jax.tree_util.tree_map(lambda g: g(rows), getters)


def _table_getter(table, table_batched, index, index_batched, axis_size: int, k: int):
    """Rows (flat indices over the batch) of a :class:`TableRows` argument."""
    n = axis_size * k

    def get(rows):
        i = index.reshape(n)[rows] if index_batched else index[rows % k]
        if not table_batched:
            return table[i]
        m = table.shape[1]
        return table.reshape((axis_size * m,) + table.shape[2:])[(rows // k) * m + i]

    return get


def reset_where(reset, done, key, params, fraction: float = 1 / 8, min_rows: int = 8):
    """``reset(key, params)`` of an environment whose episode is ``done`` (zeros where it is not), computed only
    where needed: under ``vmap`` only the finished environments of the batch reset (:func:`sparse_map`, one row
    per environment; ``fraction``: about the share of environments that finish on one step), unbatched only when
    ``done``. For auto-reset wrappers of tasks whose reset costs more than a step (a warm-up simulation)."""
    params_row = jax.tree_util.tree_map(lambda a: jnp.asarray(a)[None], params)
    out = sparse_map(lambda k, p: reset(k, p), jnp.reshape(done, (1,)), key[None], params_row, fraction=fraction,
                     min_rows=min_rows)
    return jax.tree_util.tree_map(lambda a: a[0], out)


def packed_rows(vfn, mask, *args, fraction: float = 1 / 8, min_rows: int = 64):
    """``vfn`` (batched over the leading axis) on the rows ``k`` of ``args`` where ``mask[k]``
    (``mask``: ``[n]``), zeros elsewhere: the masked rows are packed (in order) into chunks of
    a fixed capacity (``max(min_rows, fraction * n)``), ``vfn`` runs on each chunk and the results
    are scattered back; a ``while_loop`` over chunks keeps it exact whatever the number of
    masked rows. ``sparse_map``'s batching rule, usable directly on flat rows."""
    fetch = lambda rows: jax.tree_util.tree_map(lambda a: a[rows], args)
    return _packed(vfn, mask, fetch, fraction, min_rows)


def _packed(vfn, mask, fetch, fraction: float, min_rows: int, targets=None):
    """:func:`packed_rows` with the arguments' rows given by ``fetch(row_indices)``; with ``targets``
    (``(segments_of(row_indices) -> [r, m], count)``) also the maxima per segment of ``vfn``'s second output
    (:func:`sparse_map`'s ``segments``).

    The masked rows are found without a per-row rank: the mask is packed into 32-bit words, the
    words' bit counts are summed, and each chunk locates its ``r``-th masked row by a binary search
    over those sums and a bit select within the word, so only the word counts (``n / 32``) and the
    chunks' own rows are touched besides one pass over the mask. Each masked row runs exactly once.
    """
    n = mask.shape[0]
    cap = n if n <= min_rows else min(n, max(min_rows, int(n * fraction)))  # static chunk capacity
    every = jnp.arange(n, dtype=jnp.int32)
    if cap == n:  # one chunk holds every row (few envs): no packing
        return _all_rows(vfn, mask, *fetch(every), targets=None if targets is None else (targets[0](every), targets[1]))
    words = _words(mask)
    counts = jax.lax.population_count(words).astype(jnp.int32)
    ends = jax.lax.associative_scan(jnp.add, counts)  # masked rows up to and including each word
    count = ends[-1]
    out = jax.eval_shape(lambda r: vfn(*fetch(r)), jax.ShapeDtypeStruct((n,), jnp.int32))
    if targets is not None:  # (row outputs, segment values [n, m]) -> (rows [n, ...], segment maxima [total])
        out = (out[0], jax.tree_util.tree_map(lambda v: jax.ShapeDtypeStruct((targets[1],), v.dtype), out[1]))
    out = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), out)

    def chunk(carry):
        c, out = carry
        r = c * cap + jnp.arange(cap, dtype=jnp.int32)  # ranks of the chunk's masked rows
        k = jnp.minimum(jnp.searchsorted(ends, r, side="right"), words.shape[0] - 1).astype(jnp.int32)
        within = r - (ends[k] - counts[k])
        rows = jnp.where(r < count, _select_bit(words[k], within) * words.shape[0] + k, n)
        res = vfn(*fetch(jnp.minimum(rows, n - 1)))
        if targets is None:
            return c + 1, jax.tree_util.tree_map(lambda o, v: o.at[rows].set(v, mode="drop"), out, res)
        rows_out = jax.tree_util.tree_map(lambda o, v: o.at[rows].set(v, mode="drop"), out[0], res[0])
        t = jnp.where((rows < n)[:, None], targets[0](jnp.minimum(rows, n - 1)), targets[1])
        seg_out = jax.tree_util.tree_map(lambda o, v: o.at[t].max(v, mode="drop"), out[1], res[1])
        return c + 1, (rows_out, seg_out)

    _, out = jax.lax.while_loop(lambda carry: carry[0] * cap < count, chunk, (jnp.zeros((), jnp.int32), out))
    return out


_WORD = 32  # mask bits per word


def _words(mask):
    """A boolean ``[n]`` mask as ``W = ceil(n / 32)`` ``uint32`` words: bit ``i`` of word ``w`` is
    ``mask[i W + w]`` (strided, so the packing reduces over the major axis and vectorises over the words;
    rows are independent, so the order in which they are processed does not matter)."""
    n_words = -(-mask.shape[0] // _WORD)
    x = jnp.pad(mask, (0, n_words * _WORD - mask.shape[0])).reshape(_WORD, n_words).astype(jnp.uint32)
    return jnp.sum(x << jnp.arange(_WORD, dtype=jnp.uint32)[:, None], axis=0, dtype=jnp.uint32)


def running_count(mask):
    """``jnp.cumsum(mask)`` (``[n]`` bool, int32) for short masks (one environment's vehicle slots): the mask packed
    into 32-bit words of consecutive rows, each row's count the bit count of its word up to its own bit plus the
    words before. XLA:CPU computes ``cumsum`` as a tree of reduce-windows, several times slower at this size."""
    n = mask.shape[0]
    n_words = -(-n // _WORD)
    bits = jnp.pad(mask, (0, n_words * _WORD - n)).reshape(n_words, _WORD).astype(jnp.uint32)
    words = jnp.sum(bits << jnp.arange(_WORD, dtype=jnp.uint32), axis=1, dtype=jnp.uint32)
    counts = jax.lax.population_count(words).astype(jnp.int32)
    before = jnp.cumsum(counts) - counts if n_words > 1 else jnp.zeros(1, jnp.int32)
    up_to = (np.uint64(2) << np.arange(_WORD, dtype=np.uint64)) - 1  # bits 0..i of a word
    per_row = lambda a: jnp.broadcast_to(a[:, None], (n_words, _WORD)).reshape(n_words * _WORD)[:n]
    own = jax.lax.population_count(per_row(words) & jnp.asarray(np.tile(up_to.astype(np.uint32), n_words)[:n]))
    return own.astype(jnp.int32) + per_row(before)


def _select_bit(word, j):
    """Position of the ``j``-th (from 0) set bit of ``word`` (``uint32``), by halving the bit range."""
    pos = jnp.zeros(jnp.shape(j), jnp.uint32)
    j = j.astype(jnp.uint32)
    for width in (16, 8, 4, 2, 1):
        low = jax.lax.population_count((word >> pos) & jnp.uint32((1 << width) - 1))
        up = j >= low
        j = jnp.where(up, j - low, j)
        pos = jnp.where(up, pos + jnp.uint32(width), pos)
    return pos.astype(jnp.int32)


def _all_rows(vfn, mask, *args, targets=None):
    """``vfn`` on every row when any row is masked (one ``cond``), masked rows kept, zeros elsewhere; with
    ``targets`` (``([n, m]`` segments, count)``, out of range: none) the second output's maxima per segment."""
    zeros = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), jax.eval_shape(vfn, *args))
    res = jax.lax.cond(jnp.any(mask), lambda: vfn(*args), lambda: zeros)
    res = jax.tree_util.tree_map(
        lambda r: jnp.where(mask.reshape(mask.shape + (1,) * (r.ndim - 1)), r, jnp.zeros_like(r)), res)
    if targets is None:
        return res
    t, total = targets
    return res[0], jax.tree_util.tree_map(lambda v: jnp.zeros(total, v.dtype).at[t].max(v, mode="drop"), res[1])


def grouped_rows(fn, mask, size: int):
    """``fn`` on the rows of one environment where ``mask`` (``[n]``), ``size`` rows at a time; zeros elsewhere.

    ``fn(rows)`` takes ``size`` row indices (``[size]`` ints) and returns a pytree of ``[size, ...]`` arrays, one
    entry per index; it may read anything of the environment (a closure), which :func:`sparse_map`'s rows may not.
    For per-row work that only a few of an environment's rows need on a frame (MOBIL's lane-change decisions of the
    drivers whose timer fired): the masked rows are numbered in order and a ``while_loop`` runs them ``size`` at
    a time, as many groups as there are masked rows (none on a frame where no row is masked; under ``vmap``: as
    many as the environment of the batch with the most needs). With ``size >= n`` it is ``fn`` on every row. Rows
    must be independent: a row's result may not depend on which others share its group.
    """
    n = mask.shape[0]
    every = jnp.arange(n, dtype=jnp.int32)
    if size >= n:
        out = fn(every)
        return jax.tree_util.tree_map(lambda r: jnp.where(_column(mask, r), r, jnp.zeros_like(r)), out)
    rank = running_count(mask) - 1  # order of each masked row among the masked rows
    count = rank[-1] + 1
    slots = jnp.arange(size, dtype=jnp.int32)

    def run(g, out):
        lo = g * size
        hit = mask[None, :] & (rank[None, :] == lo + slots[:, None])  # [size, n]: group entry -> row
        rows = jnp.where(jnp.any(hit, axis=1), jnp.argmax(hit, axis=1).astype(jnp.int32), 0)
        res = materialize(fn(rows))  # computed once, not once per row reading it
        mine = mask & (rank >= lo) & (rank < lo + size)
        entry = jnp.clip(rank - lo, 0, size - 1)
        return jax.tree_util.tree_map(lambda o, r: jnp.where(_column(mine, o), r[entry], o), out, res)

    shapes = jax.eval_shape(fn, slots)
    out = jax.tree_util.tree_map(lambda s: jnp.zeros((n,) + s.shape[1:], s.dtype), shapes)
    _, out = jax.lax.while_loop(lambda c: c[0] * size < count, lambda c: (c[0] + 1, run(c[0], c[1])),
                                (jnp.zeros((), jnp.int32), out))
    return out


def batch_rows(fn, mask, env, fraction: float = 1 / 12, min_rows: int = 64):
    """``fn(row, env)`` on each row of one environment where ``mask`` (``[n]``), zeros elsewhere; ``row`` is a scalar
    index and ``env`` a pytree of the environment's arrays, which ``fn`` may read whole (it may close over nothing
    traced).

    :func:`grouped_rows` with the rows of the whole batch packed together: under ``vmap`` (custom rule) an
    environment whose rows are all unmasked costs nothing and one with many masked rows no more than its rows, where
    :func:`grouped_rows` runs every environment of the batch as many times as the busiest one needs. The masked rows
    are packed into chunks (``fraction`` of the batch's rows, at least ``min_rows``; as :func:`sparse_map`), each row
    gathers its own environment's ``env``, so this suits environments of small arrays (few vehicle slots).
    Unbatched it is :func:`grouped_rows` one row at a time."""
    leaves, treedef = jax.tree_util.tree_flatten(env)
    one_row = lambda r, *ls: fn(r, jax.tree_util.tree_unflatten(treedef, ls))

    def unbatched(mask, *leaves):
        return grouped_rows(lambda rows: jax.vmap(one_row, (0,) + (None,) * len(leaves))(rows, *leaves), mask, 1)

    f = jax.custom_batching.custom_vmap(unbatched)

    @f.def_vmap
    def rule(axis_size, in_batched, mask, *leaves):
        n = mask.shape[-1]
        batched = in_batched[1:]
        vfn = jax.vmap(one_row, (0,) + tuple(0 if b else None for b in batched))
        # each packed row: its index within its environment, and that environment's arrays
        fetch = lambda rows: (rows % n,) + tuple(a[rows // n] if b else a for a, b in zip(leaves, batched))
        out = _packed(vfn, _flat_mask(mask, in_batched[0], axis_size), fetch, fraction, min_rows)
        return _per_environment(out, axis_size, n)

    return f(mask, *leaves)


def _column(mask, like):
    """``mask`` (``[n]``) shaped to broadcast against ``like`` (``[n, ...]``)."""
    return mask.reshape(mask.shape + (1,) * (like.ndim - 1))
