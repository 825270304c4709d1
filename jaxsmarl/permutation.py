"""The minibatch shuffle of the on-policy updates: a uniformly random permutation, cheaper on XLA:CPU than
``jax.random.permutation``."""

from __future__ import annotations

import math
import operator

import jax
import jax.numpy as jnp

__all__ = ["random_permutation"]


def random_permutation(key, n: int):
    """A uniformly random permutation of ``range(n)`` (int32), by sorts of single packed ``uint32`` keys.

    ``jax.random.permutation`` shuffles with ``ceil(3 ln n / ln(2^32 - 1))`` rounds of a stable key-value sort
    (random keys, the array as values), several times the cost of sorting plain ``uint32``s on XLA:CPU. Here each
    round packs ``32 - b`` random bits (``b = ceil(log2 n)``) above the
    element's current position (the low ``b`` bits), sorts those distinct keys and reads the positions back
    from the low bits: equal random parts keep the previous order, as in jax's stable rounds. The number of
    rounds keeps jax's collision standard (at least ``3 log2 n`` random bits per element in all): 3 rounds of 19
    bits for n = 8192 (jax: 2 rounds of 32 bits). Beyond ``n = 2^24`` (fewer than 8 random bits per round) it is
    ``jax.random.permutation``.
    """
    try:
        size = operator.index(n)
    except TypeError:
        size = 0
    if size < 1:
        raise ValueError(f"random_permutation: n must be a positive int, got {n!r}")
    n = size
    b = max(1, (n - 1).bit_length())
    if b > 24:
        return jax.random.permutation(key, n).astype(jnp.int32)
    rounds = math.ceil(3 * math.log2(max(n, 2)) / (32 - b))
    low = jnp.uint32((1 << b) - 1)
    position = jnp.arange(n, dtype=jnp.uint32)
    perm = jnp.arange(n, dtype=jnp.int32)
    for k in jax.random.split(key, rounds):
        packed = (jax.random.bits(k, (n,), jnp.uint32) & ~low) | position
        perm = perm[(jax.lax.sort(packed) & low).astype(jnp.int32)]
    return perm
