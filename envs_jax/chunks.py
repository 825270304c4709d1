"""``in_chunks``: under ``vmap`` on the CPU, run a function over the batch a few environments at a time."""

from __future__ import annotations

import jax


def in_chunks(fn, rows: int | None):
    """``fn``, which under ``vmap`` on the CPU runs over the batch ``rows`` environments at a time.

    For per-environment work with large intermediates (a traffic step's ``[V, 4, N]`` neighbour coordinates):
    vectorised over thousands of environments at once, each intermediate makes a round trip through memory,
    where a chunk's stay in the cache (``lax.map`` with ``batch_size``; a remainder runs as one smaller chunk).
    Results are ``vmap(fn)``'s up to the last bit that any change of batch width may round differently
    (XLA:CPU vectorises a batch's bulk and its tail differently). On other backends, with ``rows=None`` or a batch
    of at most ``rows``, it is ``vmap(fn)`` itself: accelerators want the whole batch at once. The chunk applies to
    the innermost ``vmap``; an outer one (over seeds) multiplies it.
    """
    if rows is None:
        return fn
    if rows < 1:
        raise ValueError(f"in_chunks: rows must be a positive number of environments or None, got {rows}")
    f = jax.custom_batching.custom_vmap(fn)

    @f.def_vmap
    def rule(axis_size, in_batched, *args):
        flat, tree = jax.tree_util.tree_flatten(args)
        flags = jax.tree_util.tree_leaves(in_batched)
        if axis_size <= rows or jax.default_backend() != "cpu":
            in_axes = jax.tree_util.tree_unflatten(tree, [0 if b else None for b in flags])
            out = jax.vmap(fn, in_axes=tuple(in_axes))(*args)
        else:
            def one(batched):  # one environment: its batched leaves with the shared ones
                it = iter(batched)
                return fn(*jax.tree_util.tree_unflatten(tree, [next(it) if b else a for a, b in zip(flat, flags)]))

            out = jax.lax.map(one, [a for a, b in zip(flat, flags) if b], batch_size=rows)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return f
