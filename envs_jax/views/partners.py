"""Policies for the agents a single-agent view does not control: ``policy(key, obs) -> actions``.

``obs`` is ``[M, obs_dim]`` (the M = K - 1 other agents, in agent order) and the result ``[M]``
integer meta-actions or ``[M, d]`` floats in ``[-1, 1]``; the function must be jittable (it runs
inside the view's compiled step). Any such function works, e.g. a trained policy's forward pass.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs_jax.views.spaces import IDLE


def idle_policy(env):
    """Every other agent keeps its lane and speed (IDLE), or applies zero acceleration and steering."""
    if env.discrete:
        return lambda key, obs: jnp.full(obs.shape[:1], IDLE, jnp.int32)
    return lambda key, obs: jnp.zeros(obs.shape[:1] + (int(env.action_dim),), jnp.float32)


def random_policy(env):
    """Uniform random actions for every other agent."""
    if env.discrete:
        return lambda key, obs: jax.random.randint(key, obs.shape[:1], 0, int(env.num_actions))
    return lambda key, obs: jax.random.uniform(key, obs.shape[:1] + (int(env.action_dim),), minval=-1.0, maxval=1.0)
