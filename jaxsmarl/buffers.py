"""Device-resident uniform replay buffer (Algorithm 1: "store (s, a_i, r_i, c_i, d, s') into D").

A pure-functional FIFO ring over any pytree of transitions: ``init`` allocates ``capacity`` slots shaped like
one example item, ``add`` writes a batch of items (wrapping around and overwriting the oldest), ``sample``
draws uniformly WITH replacement from the filled slots (as the authors' ``np.random.randint``, §7).
All functions are jit/vmap-safe; the state is a flax struct, so it checkpoints like any pytree.

Differences to the authors' buffer: once full it overwrites the oldest slot (theirs: a random slot); their
merge/roundabout runs never fill the 5e5 buffer, so this never matters at their budgets.
"""

from __future__ import annotations

from typing import Any

import flax.struct
import jax
import jax.numpy as jnp

__all__ = ["BufferState", "init", "add", "sample", "can_sample"]


@flax.struct.dataclass
class BufferState:
    data: Any  # pytree, every leaf [capacity, ...]
    pos: jax.Array  # int32, next slot to write
    size: jax.Array  # int32, number of valid slots (<= capacity)

    @property
    def capacity(self) -> int:
        return jax.tree.leaves(self.data)[0].shape[0]


def init(example_item: Any, capacity: int) -> BufferState:
    """Empty buffer with ``capacity`` slots shaped and typed like ``example_item`` (a pytree of arrays)."""
    if int(capacity) < 1:
        raise ValueError(f"buffer capacity must be >= 1, got {capacity}")
    data = jax.tree.map(lambda x: jnp.zeros((int(capacity),) + jnp.shape(x), jnp.asarray(x).dtype), example_item)
    return BufferState(data=data, pos=jnp.int32(0), size=jnp.int32(0))


def add(state: BufferState, items: Any) -> BufferState:
    """Append a batch of items (every leaf ``[n, ...]``), in order, wrapping around at the capacity.

    ``n`` may exceed the capacity; then only the last ``capacity`` items survive (as in sequential writes).
    """
    cap = state.capacity
    n = jax.tree.leaves(items)[0].shape[0]
    idx = (state.pos + jnp.arange(n, dtype=jnp.int32)) % cap
    if n > cap:  # keep the last `cap` items so that duplicate indices never race
        items = jax.tree.map(lambda x: x[n - cap :], items)
        idx = idx[n - cap :]
    data = jax.tree.map(lambda buf, x: buf.at[idx].set(x.astype(buf.dtype), unique_indices=True), state.data, items)
    return BufferState(
        data=data,
        pos=((state.pos + n) % cap).astype(jnp.int32),
        size=jnp.minimum(state.size + n, cap).astype(jnp.int32),
    )


def sample(state: BufferState, key: jax.Array, batch_size: int) -> Any:
    """``batch_size`` items drawn uniformly with replacement from the filled slots (slot 0 if empty)."""
    idx = jax.random.randint(key, (batch_size,), 0, jnp.maximum(state.size, 1))
    return jax.tree.map(lambda x: x[idx], state.data)


def can_sample(state: BufferState, min_size: int) -> jax.Array:
    """True once at least ``min_size`` transitions are stored (the authors' warm-up ``sample_size``)."""
    return state.size >= min_size
