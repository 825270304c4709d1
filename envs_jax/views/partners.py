"""Policies for the agents a single-agent view does not control: ``policy(key, obs) -> actions``.

``obs`` is ``[M, *obs_shape]`` (the M = K - 1 other agents, in agent order; ``obs_shape`` is one
agent's observation shape, e.g. ``(8,)``, ``(vehicles_count, F)`` or ``(C, H, W)``) and the
result ``[M]`` integer meta-actions or ``[M, d]`` floats in ``[-1, 1]``; the function must be
jittable (it runs inside the view's compiled step). Any such function works, e.g. a trained
policy's forward pass. A single-agent task (K = 1) needs none.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs_jax.views.spaces import AgentSpec


def idle_policy(env):
    """Every other agent keeps its lane and speed (IDLE), or applies zero acceleration and steering."""
    spec = AgentSpec.of(env)
    if spec.discrete:
        return lambda key, obs: jnp.full(obs.shape[:1], spec.idle_action, jnp.int32)
    return lambda key, obs: jnp.zeros(obs.shape[:1] + (spec.action_dim,), jnp.float32)


def random_policy(env):
    """Uniform random actions for every other agent."""
    spec = AgentSpec.of(env)
    if spec.discrete:
        return lambda key, obs: jax.random.randint(key, obs.shape[:1], 0, spec.num_actions)
    return lambda key, obs: jax.random.uniform(key, obs.shape[:1] + (spec.action_dim,), minval=-1.0, maxval=1.0)
