"""``materialize``: compute a value once into a buffer that its consumers read.

XLA fuses cheap elementwise producers (selects, compares, sines and cosines count as
cheap) into *every* consumer, so an array read through several slices or broadcasts
is recomputed by each of them: a per-vehicle cosine broadcast over vehicle pairs
runs once per pair, and a neighbour search read column by column runs once per
column. ``jax.lax.optimization_barrier`` does not prevent this on the CPU (the CPU
compiler removes barriers before fusion), so here the value passes through a
``while_loop`` whose trip count XLA cannot see (it is always one): loop outputs are
buffers, and fusion stops there. The value is returned unchanged, bit for bit.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def _through_loop(leaves):
    # one trip, but the count reads the data, so XLA can neither inline nor drop the loop
    probe = leaves[0].reshape(-1)[:1].astype(jnp.float32)  # a float: XLA folds ``x != x`` for integers
    trips = 1 + jnp.minimum(jnp.sum(probe != probe), 0).astype(jnp.int32)

    def body(carry):
        i, xs = carry
        return i + 1, tuple(jnp.where(i < 0, jnp.zeros_like(x), x) for x in xs)

    return jax.lax.while_loop(lambda c: c[0] < trips, body, (jnp.zeros((), jnp.int32), tuple(leaves)))[1]


@jax.custom_batching.custom_vmap
def _materialize(*leaves):
    return _through_loop(leaves)


@_materialize.def_vmap
def _materialize_batched(axis_size, in_batched, *leaves):
    # one loop over the whole batch (not a batched loop, which would add a select per trip)
    return _materialize(*leaves), tuple(in_batched)


def materialize(tree):
    """``tree`` (a pytree of arrays), unchanged, computed once before any consumer reads it."""
    leaves, treedef = jax.tree_util.tree_flatten(tree)
    if not leaves:
        return tree
    return jax.tree_util.tree_unflatten(treedef, list(_materialize(*leaves)))
