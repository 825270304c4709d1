"""Weight initialisers built from plain XLA operations.

:func:`orthogonal_init` makes orthogonal matrices by Gram-Schmidt instead of ``jax.nn.initializers.orthogonal``:
that one calls LAPACK's QR, whose XLA:CPU kernel blocks a thread of the intra-op pool while it waits for work it
queued on the same pool, so two seed shards initialising at once on a 2-core machine deadlock.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["orthogonal_init"]


def orthogonal_init(scale: float = 1.0):
    """``jax.nn.initializers.orthogonal(scale)`` for 2-D kernels without a LAPACK custom call.

    Same recipe and same random draw: ``z ~ N(0, 1)`` of shape ``[max(r, c), min(r, c)]``, ``Q`` of its QR
    factorisation with a positive diagonal of ``R`` (unique, so the result equals jax's up to rounding),
    transposed when the kernel has fewer rows than columns, times ``scale``. ``Q`` is built column by column by
    Gram-Schmidt with re-orthogonalisation ("twice is enough"), in a ``fori_loop`` of matrix-vector products:
    no custom call that could block an XLA:CPU pool thread (see the module docstring).
    """

    def init(key, shape, dtype=None):
        if len(shape) != 2:
            raise ValueError(f"orthogonal_init: 2-D kernels only, got shape {shape}")
        dtype = dtype or jnp.zeros(()).dtype
        r, c = shape
        n, m = max(r, c), min(r, c)
        z = jax.random.normal(key, (n, m), dtype)

        def column(j, q):
            v = z[:, j]
            for _ in range(2):  # columns >= j of q are still zero, so this projects on the finished ones
                v = v - q @ (q.T @ v)
            return q.at[:, j].set(v / jnp.linalg.norm(v))

        q = jax.lax.fori_loop(0, m, column, jnp.zeros((n, m), dtype))
        q = q.T if r < c else q
        return jnp.asarray(scale, dtype) * q

    return init
