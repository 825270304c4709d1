"""The critic loss and masked statistics of MAPPO-L and MACPO: the clipped value loss with the Huber loss (clip 0.2,
delta 10), masked means and the advantage standardisation."""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["huber", "masked_mean", "value_loss", "standardize"]


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
