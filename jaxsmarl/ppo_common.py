"""Building blocks shared by MAPPO-L and MACPO (docs/algorithms.md, MAPPO-L and MACPO): networks, the Gaussian policy,
running normalisers and the critic loss.

* :class:`MLP`: the reference ``MLPBase`` (MACPO-repo ``algorithms/utils/mlp.py``): ``LayerNorm(obs)`` (feature
  normalisation) -> ``Linear + ReLU + LayerNorm`` -> ``layer_n x [Linear + ReLU + LayerNorm]`` -> linear head;
  orthogonal weights with the ReLU gain sqrt(2), zero biases, head gain 0.01 for the policy and 1 for critics.
  The orthogonal matrices come from :func:`orthogonal_init` (Gram-Schmidt in plain XLA ops), not from
  ``jax.nn.initializers.orthogonal``: that one calls LAPACK's QR, whose XLA:CPU kernel blocks a thread of the
  intra-op pool while it waits for work it queued on the same pool, so two seed shards initialising at once on
  a 2-core machine deadlock.
* Gaussian policy with a state-independent bounded standard deviation (``DiagGaussian``):
  ``std = sigmoid(log_std / x_coef) * y_coef``, ``log_std`` initialised to ``x_coef`` (std 0.5 sigmoid(1) = 0.37).
* :class:`RunningStats`: running mean / variance (Chan et al.'s parallel update), used for the observation
  normalisation and for the value-target normalisation (the reference's ValueNorm; one per critic here instead
  of the reference's shared reward normaliser, a documented deviation).
* :func:`value_loss`: clipped value loss with the Huber loss (clip 0.2, delta 10).
* :func:`random_permutation`: the minibatch shuffle, like ``jax.random.permutation`` but cheaper on XLA:CPU.
* :func:`mlp_columns`: :class:`MLP` on column samples (:mod:`jaxsmarl.columns`), for the update's gradients.
* :func:`mlp_rows`: :class:`MLP` whose reverse mode takes weight gradients from transposed layer inputs
  (:func:`jaxsmarl.columns.affine_rows`), for MACPO's Fisher products.
* :class:`Flat`, :func:`to_flat`, :func:`from_flat`: a network's parameters and its optimiser state as single
  vectors for the minibatch loops (one Adam step over one vector instead of one per parameter array).
"""

from __future__ import annotations

import math
import operator
from typing import Callable

import flax.linen as nn
import flax.struct
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from jaxsmarl import columns

__all__ = ["MLP", "mlp_columns", "mlp_rows", "Flat", "to_flat", "from_flat", "random_permutation", "orthogonal_init",
           "std_from_param", "gaussian_log_prob", "gaussian_entropy", "gaussian_kl", "RunningStats", "huber",
           "value_loss", "masked_mean", "standardize"]


def random_permutation(key, n: int):
    """A uniformly random permutation of ``range(n)`` (int32), by sorts of single packed ``uint32`` keys.

    ``jax.random.permutation`` shuffles with ``ceil(3 ln n / ln(2^32 - 1))`` rounds of a stable key-value sort
    (random keys, the array as values), several times the cost of sorting plain ``uint32``s on XLA:CPU. Here each round packs ``32 - b`` random bits (``b = ceil(log2 n)``) above the
    element's current position (the low ``b`` bits), sorts those distinct keys and reads the positions back
    from the low bits: equal random parts keep the previous order, as in jax's stable rounds. The number of
    rounds keeps jax's collision standard (at least ``3 log2 n`` random bits per element in all): 3 rounds of 19
    bits for n = 8192 (jax: 2 rounds of 32 bits). Beyond ``n = 2^24`` (fewer than 8 random bits per round) it is ``jax.random.permutation``.
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


@flax.struct.dataclass
class Flat:
    """A parameter tree raveled into one vector (``jax.flatten_util.ravel_pytree``), ``tree()`` to use it.

    Carried through the minibatch loops on XLA:CPU: optax then clips and steps one vector per network (a few
    kernels) instead of each of its arrays (several small kernels each), and the
    gradient arrives as one vector. Same values as the tree form up to summation order (the global norm)."""

    vec: jax.Array
    unravel: Callable = flax.struct.field(pytree_node=False)

    def tree(self):
        return self.unravel(self.vec)


def to_flat(params, opt_state):
    """``(Flat(params), opt_state)`` with every parameter-shaped part of ``opt_state`` (Adam's moments) a
    :class:`Flat` too; :func:`from_flat` is the inverse."""
    vec, unravel = ravel_pytree(params)
    treedef = jax.tree.structure(params)
    is_params = lambda x: isinstance(x, dict) and jax.tree.structure(x) == treedef
    opt = jax.tree.map(lambda s: Flat(ravel_pytree(s)[0], unravel) if is_params(s) else s, opt_state,
                       is_leaf=is_params)
    return Flat(vec, unravel), opt


def from_flat(params: Flat, opt_state):
    """The trees back from :func:`to_flat`'s forms."""
    is_flat = lambda x: isinstance(x, Flat)
    return params.tree(), jax.tree.map(lambda s: s.tree() if is_flat(s) else s, opt_state, is_leaf=is_flat)


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
        if self.feature_norm:
            x = nn.LayerNorm(epsilon=1e-5)(x)
        for _ in range(1 + self.layer_n):
            x = nn.Dense(self.hidden, kernel_init=orthogonal_init(relu_gain),
                         bias_init=nn.initializers.zeros)(x)
            x = nn.LayerNorm(epsilon=1e-5)(nn.relu(x))
        return nn.Dense(self.out_dim, kernel_init=orthogonal_init(self.out_gain),
                        bias_init=nn.initializers.zeros)(x)


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
    shift = 0 if feature_norm else 1  # the LayerNorm before Dense_j is LayerNorm_{j - shift}
    for j in range(2 + layer_n):
        d = p[f"Dense_{j}"]
        kernel, bias = d["kernel"], d["bias"]
        if j >= shift:
            norm = p[f"LayerNorm_{j - shift}"]
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
    norm = lambda j, h: nn.LayerNorm(epsilon=1e-5).apply({"params": p[f"LayerNorm_{j}"]}, h)
    shift = 0 if feature_norm else 1
    if feature_norm:
        x = norm(0, x)
    for j in range(2 + layer_n):
        x = columns.affine_rows(p[f"Dense_{j}"]["kernel"], p[f"Dense_{j}"]["bias"], x)
        if j == 1 + layer_n:
            return x
        x = norm(j + 1 - shift, jax.nn.relu(x))


def std_from_param(log_std, x_coef: float, y_coef: float):
    """``sigmoid(log_std / x_coef) * y_coef``: bounded in (0, y_coef)."""
    return jax.nn.sigmoid(log_std / x_coef) * y_coef


def gaussian_log_prob(action, mean, std):
    """Log-density of a diagonal Gaussian, summed over the last (action) axis."""
    z = (action - mean) / std
    return jnp.sum(-0.5 * z * z - jnp.log(std) - 0.5 * math.log(2.0 * math.pi), axis=-1)


def gaussian_entropy(std):
    return jnp.sum(0.5 + 0.5 * math.log(2.0 * math.pi) + jnp.log(std), axis=-1)


def gaussian_kl(mean_old, std_old, mean, std):
    """``KL(old || new) = log(s/s_old) + (s_old^2 + (m_old - m)^2) / (2 s^2) - 1/2`` summed over action dims
    (with the reference's 1e-8). safepo's ``kl_divergence`` writes ``log(s_old) - log(s)``, which is not a KL
    (its gradient in s does not vanish at s = s_old); we use the true divergence, whose Hessian there is the
    Fisher matrix."""
    kl = (jnp.log(std) - jnp.log(std_old) + (std_old ** 2 + (mean_old - mean) ** 2) / (1e-8 + 2.0 * std ** 2)
          - 0.5)
    return jnp.sum(kl, axis=-1)


@flax.struct.dataclass
class RunningStats:
    """Running mean and variance over a batch axis, per element of ``mean.shape``."""

    count: jax.Array
    mean: jax.Array
    var: jax.Array

    @classmethod
    def create(cls, shape, dtype=None):
        dtype = dtype or jnp.zeros(()).dtype
        return cls(jnp.zeros(shape, dtype), jnp.zeros(shape, dtype), jnp.ones(shape, dtype))

    def update(self, x, mask=None):
        """Merge the samples ``x[..., *shape]`` (leading axes are samples). ``mask`` (per sample, or per
        element like ``x``) selects what is merged; counts are kept per element."""
        lead = x.ndim - self.mean.ndim
        axes = tuple(range(lead))
        w = jnp.ones(x.shape, x.dtype) if mask is None else jnp.asarray(mask, x.dtype)
        w = jnp.broadcast_to(w.reshape(w.shape + (1,) * (x.ndim - w.ndim)), x.shape)
        n = jnp.sum(w, axis=axes)
        n_b = jnp.maximum(n, 1.0)
        m_b = jnp.sum(w * x, axis=axes) / n_b
        v_b = jnp.sum(w * (x - m_b) ** 2, axis=axes) / n_b
        tot = self.count + n
        frac = n / jnp.maximum(tot, 1.0)
        delta = m_b - self.mean
        mean = self.mean + delta * frac
        m2 = self.var * self.count + v_b * n + delta ** 2 * self.count * frac
        var = jnp.where(tot > 0, m2 / jnp.maximum(tot, 1.0), self.var)
        return RunningStats(tot, mean, var)

    def normalize(self, x, clip: float = 10.0):
        y = (x - self.mean) / jnp.sqrt(self.var + 1e-8)
        return jnp.clip(y, -clip, clip)

    def denormalize(self, y):
        return y * jnp.sqrt(self.var + 1e-8) + self.mean


def huber(e, delta: float):
    a = jnp.abs(e)
    return jnp.where(a <= delta, 0.5 * e * e, delta * (a - 0.5 * delta))


def masked_mean(x, mask):
    mask = jnp.asarray(mask, x.dtype)
    return jnp.sum(x * mask) / jnp.maximum(jnp.sum(mask), 1.0)


def value_loss(pred, old_pred, target, mask, clip: float, delta: float):
    """``max(huber(target - v), huber(target - v_clipped))``, ``v_clipped = v_old + clip(v - v_old, +-clip)``."""
    clipped = old_pred + jnp.clip(pred - old_pred, -clip, clip)
    loss = jnp.maximum(huber(target - pred, delta), huber(target - clipped, delta))
    return masked_mean(loss, mask)


def standardize(x, mask, eps: float = 1e-5):
    """``(x - mean) / (std + eps)`` over the entries where ``mask`` (the reference's advantage standardisation)."""
    m = masked_mean(x, mask)
    var = masked_mean((x - m) ** 2, mask)
    return (x - m) / (jnp.sqrt(var) + eps)
