"""The categorical policy of MAPPO-L and MACPO on discrete actions (docs/algorithms.md, discrete actions and K
agents): the actor's outputs are logits; log-probabilities, entropy and the KL divergence in closed form."""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["categorical_log_prob", "categorical_entropy", "categorical_kl"]


def categorical_log_prob(action, logits):
    """``log softmax(logits)[action]``: ``logits [..., A]``, integer ``action [...]`` in ``0..A-1``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), axis=-1)[..., 0]


def categorical_entropy(logits):
    """``-sum_a p_a log p_a`` over the last axis."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


def categorical_kl(logits_old, logits):
    """``KL(old || new) = sum_a p_old,a (log p_old,a - log p_new,a)`` over the last axis; its Hessian in the new
    logits at ``logits = logits_old`` is the Fisher matrix ``diag(p) - p p^T``."""
    logp_old = jax.nn.log_softmax(logits_old, axis=-1)
    return jnp.sum(jnp.exp(logp_old) * (logp_old - jax.nn.log_softmax(logits, axis=-1)), axis=-1)
