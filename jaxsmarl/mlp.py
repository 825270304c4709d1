"""The actor and critic network of MAPPO-L and MACPO and its factory, :func:`make_mlp` (docs/design.md, networks
and layouts).

:class:`MLP` is the reference ``MLPBase`` (docs/algorithms.md, MAPPO-L and MACPO): ``LayerNorm(obs)`` (feature
normalisation) -> ``Linear + ReLU + LayerNorm`` -> ``layer_n x [Linear + ReLU + LayerNorm]`` -> linear head;
orthogonal weights with the ReLU gain sqrt(2) (:func:`jaxsmarl.initializers.orthogonal_init`), zero biases, head
gain 0.01 for the policy and 1 for critics. Its layers are named by :func:`dense_name` and :func:`norm_name`; the
twins below read the parameters by those names:

* :func:`mlp_columns`: the same function on column samples (:mod:`jaxsmarl.columns`), for the update's gradients;
* :func:`mlp_rows`: the same function whose reverse mode takes weight gradients from transposed layer inputs
  (:func:`jaxsmarl.columns.affine_rows`), for MACPO's Fisher products.
"""

from __future__ import annotations

import math

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxsmarl import columns
from jaxsmarl.initializers import orthogonal_init
from jaxsmarl.layout import layout as current_layout
from jaxsmarl.network import Network

__all__ = ["MLP", "make_mlp", "mlp_columns", "mlp_rows", "dense_name", "norm_name"]


def dense_name(j: int) -> str:
    """The parameter name of the ``j``-th dense layer (the head is the last); the names flax's automatic naming
    gave, so that trees written before stay valid."""
    return f"Dense_{j}"


def norm_name(j: int) -> str:
    """The parameter name of the ``j``-th LayerNorm (with ``feature_norm`` the input's is the 0-th)."""
    return f"LayerNorm_{j}"


def _norm_after(j: int, feature_norm: bool) -> str:
    """The LayerNorm after dense layer ``j`` (``j = -1``: the input's, with ``feature_norm``)."""
    return norm_name(j + int(feature_norm))


class MLP(nn.Module):
    """The reference actor/critic trunk with a linear head of ``out_dim`` outputs."""

    hidden: int = 64
    layer_n: int = 1
    out_dim: int = 1
    out_gain: float = 1.0
    feature_norm: bool = True

    @nn.compact
    def __call__(self, x):
        relu_gain = math.sqrt(2.0)
        dtype = jnp.zeros(()).dtype  # the default float: float32, or float64 under jax_enable_x64 (parity runs)
        if self.feature_norm:
            x = nn.LayerNorm(epsilon=1e-5, param_dtype=dtype, name=_norm_after(-1, True))(x)
        for j in range(1 + self.layer_n):
            x = nn.Dense(self.hidden, kernel_init=orthogonal_init(relu_gain), bias_init=nn.initializers.zeros,
                         param_dtype=dtype, name=dense_name(j))(x)
            x = nn.LayerNorm(epsilon=1e-5, param_dtype=dtype, name=_norm_after(j, self.feature_norm))(nn.relu(x))
        return nn.Dense(self.out_dim, kernel_init=orthogonal_init(self.out_gain), bias_init=nn.initializers.zeros,
                        param_dtype=dtype, name=dense_name(1 + self.layer_n))(x)


def _normalize_columns(x, eps: float = 1e-5):
    """flax ``LayerNorm``'s normalisation over the feature axis 0 of ``x [features, B]``, without its scale and
    offset (:func:`mlp_columns` folds those into the next layer)."""
    return nn.LayerNorm(epsilon=eps, reduction_axes=0, feature_axes=0, use_scale=False, use_bias=False).apply({}, x)


def mlp_columns(params, xt, layer_n: int = 1, feature_norm: bool = True):
    """:class:`MLP` on samples stored as columns: ``xt [in, B] -> [out, B]``, with the module's own parameters.

    The same function as ``MLP.apply(params, xt.T).T`` with faster reverse-mode gradients on XLA:CPU
    (:mod:`jaxsmarl.columns`); no forward-mode derivative. Each LayerNorm's scale ``s`` and offset ``o`` are
    folded into the dense layer after it: ``W^T (s * xhat + o) + b = (s W)^T xhat + (o W + b)``, so that every
    sum over the samples of the backward pass (LayerNorm and bias gradients) happens inside the layers' weight
    and bias products instead of as separate reductions of ``[64, B]`` arrays, and the input LayerNorm, which
    has no parameter before it, needs no input gradient at all.
    """
    p = params["params"]
    # behind a barrier: else XLA normalises the input in its row layout (it is the transpose of one) and the
    # first weight gradient becomes a product contracting the first axes, the slow kind (see jaxsmarl.columns)
    x = jax.lax.optimization_barrier(_normalize_columns(xt) if feature_norm else xt)
    for j in range(2 + layer_n):
        d = p[dense_name(j)]
        kernel, bias = d["kernel"], d["bias"]
        if j > 0 or feature_norm:  # fold the LayerNorm before this layer into it
            norm = p[_norm_after(j - 1, feature_norm)]
            kernel, bias = norm["scale"][:, None] * d["kernel"], bias + norm["bias"] @ d["kernel"]
        h = columns.affine(kernel, bias, x)
        if j == 1 + layer_n:
            return h
        x = _normalize_columns(jax.nn.relu(h))


def mlp_rows(params, x, layer_n: int = 1, feature_norm: bool = True):
    """:class:`MLP` with its dense layers as :func:`columns.affine_rows`: the same function of the same
    parameters, whose reverse mode makes the weight gradients from transposed copies of the layers' inputs taken
    on the forward pass (for a vjp replayed many times at one point); no forward-mode derivative."""
    p = params["params"]
    norm = lambda j, h: nn.LayerNorm(epsilon=1e-5).apply({"params": p[_norm_after(j, feature_norm)]}, h)
    if feature_norm:
        x = norm(-1, x)
    for j in range(2 + layer_n):
        x = columns.affine_rows(p[dense_name(j)]["kernel"], p[dense_name(j)]["bias"], x)
        if j == 1 + layer_n:
            return x
        x = norm(j, jax.nn.relu(x))


def _stack_shape(stacked) -> tuple:
    """The leading (stack) axes of stacked :class:`MLP` parameters: those before the first kernel's two axes."""
    kernel = stacked["params"][dense_name(0)]["kernel"]
    return kernel.shape[:-2]


def make_mlp(in_dim: int, hidden: int = 64, layer_n: int = 1, out_dim: int = 1, out_gain: float = 1.0,
             feature_norm: bool = True) -> Network:
    """:class:`MLP` as a :class:`jaxsmarl.network.Network` on ``in_dim`` inputs, in the layout of
    :func:`jaxsmarl.layout.layout`. ``apply_stack(stacked, x [B, in]) -> [*stack, B, out]``: in the column layout
    each network on its own, ``chunk`` samples at a time (:func:`jaxsmarl.columns.in_chunks`); in the row layout
    ``vmap``-ed over the stack."""
    module = MLP(hidden, layer_n, out_dim, out_gain, feature_norm)
    lay = current_layout()

    def init(key):
        return module.init(key, jnp.zeros((1, in_dim), jnp.zeros(()).dtype))

    if lay == "rows":
        def apply_stack(stacked, x):
            fn = lambda p: module.apply(p, x)
            for _ in _stack_shape(stacked):
                fn = jax.vmap(fn)
            return fn(stacked)

        return Network(lay, init, module.apply, module.apply, module.apply, apply_stack, rollout=_whole)

    def apply_update(params, x):
        return mlp_columns(params, x.T, layer_n, feature_norm).T

    def apply_replay(params, x):
        return mlp_rows(params, x, layer_n, feature_norm)

    def apply_stack(stacked, x):
        shape = _stack_shape(stacked)
        nets = [jax.tree.map(lambda w: w[ix], stacked) for ix in np.ndindex(*shape)]

        def part(xc):  # [chunk, in] -> [chunk, *stack, out], the networks one after the other
            outs = jnp.stack([mlp_columns(net, xc.T, layer_n, feature_norm) for net in nets])  # [n, out, chunk]
            return jnp.moveaxis(outs, -1, 0).reshape((xc.shape[0],) + shape + (out_dim,))

        return jnp.moveaxis(columns.in_chunks(part, x), 0, -2)

    return Network(lay, init, module.apply, apply_update, apply_replay, apply_stack, rollout=columns.in_chunks)


def _whole(fn, *xs):
    """``fn(*xs)`` at once (the row layout's way over a rollout)."""
    return fn(*xs)
