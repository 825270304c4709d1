"""Linearly decaying exploration parameters (the authors' schedules, docs/algorithms.md).

A parameter starts at ``start`` and falls by ``decay`` per environment step down to its floor:
``max(floor, start - decay * step)``, per agent. CSQ's exploration probability and MADDPG's random-action
probability and action-noise scale follow it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["linear_decay"]


def linear_decay(start, floor, decay: float, env_step) -> jax.Array:
    """``max(floor, start - decay * env_step)`` in float32; ``start``/``floor``: one value per agent."""
    start, floor = jnp.asarray(start, jnp.float32), jnp.asarray(floor, jnp.float32)
    return jnp.maximum(floor, start - decay * jnp.asarray(env_step, jnp.float32))
