"""Dense layers on samples stored as columns (``x [features, B]``), for fast gradients on XLA:CPU.

With samples as rows, reverse-mode autodiff of ``x @ W`` computes the weight gradient as ``x^T @ g``, a product
that contracts the sample axis of both operands in first position; XLA:CPU hands that layout to a generic kernel
that runs several times slower than a row-major ``[m, k] @ [k, n]`` product of the same size (YNNPACK takes only
the latter).
With samples as columns every product of a dense layer can be made row-major: the forward pass ``W^T @ x`` (the
small kernel transposed explicitly), the input gradient ``W @ g`` and the weight gradient ``x @ g^T``, which
contracts the last axes of both operands (~as fast as a forward product). :func:`dense` is that layer with its
own reverse-mode rule; it computes exactly ``(x^T @ W)^T``, so networks built on it share their parameters
(flax ``kernel [in, out]``) with the row-layout modules. It has no forward-mode derivative (``jax.jvp``).

:func:`affine_rows` keeps samples as rows and makes the weight gradient from a transposed copy of the input taken
on the forward pass: for a vjp evaluated many times at one point (MACPO's Fisher products), where the copy is made
once.

MACPO's actor keeps the row layout (its update is dominated by the conjugate-gradient products). Where the column
layout is used: :mod:`jaxsmarl.layout`; measurements: docs/performance.md.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["dense", "affine", "affine_rows", "in_chunks"]


@jax.custom_vjp
def affine(kernel, bias, xt):
    """``kernel^T @ xt + bias[:, None]``: ``kernel [in, out]``, ``bias [out]``, ``xt [in, B]`` -> ``[out, B]``.

    The kernel is transposed behind an optimisation barrier so that XLA keeps the transposed copy (64 x 64 for
    the reference networks) instead of folding the transpose back into the product. The bias gradient, a sum
    over the samples, is the product ``g @ 1``: XLA:CPU reduces the minor axis of a ``[64, 512]`` array (its
    tree-reduction rewrite: a reduce-window, then a reduce) several times slower than the matrix-vector product."""
    return jax.lax.optimization_barrier(kernel.T) @ xt + bias[:, None]


def _affine_fwd(kernel, bias, xt):
    return affine(kernel, bias, xt), (kernel, xt)


def _affine_bwd(res, g):
    kernel, xt = res
    ones = jnp.ones((g.shape[1],), g.dtype)
    # xt @ g^T [in, out]; g @ 1 [out]; kernel @ g [in, B]
    return jax.lax.dot_general(xt, g, (((1,), (1,)), ((), ()))), g @ ones, kernel @ g


affine.defvjp(_affine_fwd, _affine_bwd)


@jax.custom_vjp
def affine_rows(kernel, bias, x):
    """``x @ kernel + bias`` on samples as rows (``x [B, in]``), whose reverse-mode rule takes the weight gradient
    from a transposed copy of ``x`` made on the forward pass: ``x^T @ g`` as the row-major ``xt @ g``.

    For a vjp replayed many times at one point (MACPO's Fisher products), where the copy is made once."""
    return x @ kernel + bias


def _affine_rows_fwd(kernel, bias, x):
    return affine_rows(kernel, bias, x), (kernel, jax.lax.optimization_barrier(x.T))


def _affine_rows_bwd(res, g):
    kernel, xt = res
    ones = jnp.ones((g.shape[0],), g.dtype)
    return xt @ g, ones @ g, g @ jax.lax.optimization_barrier(kernel.T)


affine_rows.defvjp(_affine_rows_fwd, _affine_rows_bwd)


def dense(params, xt):
    """A flax ``Dense`` (``{"kernel": [in, out], "bias": [out]}``) on column samples: ``[in, B] -> [out, B]``."""
    return affine(params["kernel"], params["bias"], xt)


def in_chunks(fn, *xs, chunk: int = 512):
    """``fn(*xs)`` for a function of the samples of ``xs`` (arrays ``[B, ...]``, rows independent; outputs
    ``[B, ...]``), computed on ``chunk`` samples at a time (``lax.map``; the inputs zero-padded to a whole number
    of chunks).

    For the forward passes over a whole rollout (8192 samples): a network's ``[B, 64]`` intermediates then stay in
    the core's cache instead of streaming through memory."""
    B = xs[0].shape[0]
    if B <= chunk:
        return fn(*xs)
    n = -(-B // chunk)
    padded = tuple(jnp.pad(x, ((0, n * chunk - B),) + ((0, 0),) * (x.ndim - 1)).reshape((n, chunk) + x.shape[1:])
                   for x in xs)
    out = jax.lax.map(lambda c: fn(*c), padded)
    return jax.tree.map(lambda y: y.reshape((n * chunk,) + y.shape[2:])[:B], out)
