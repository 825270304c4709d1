"""Generalised advantage estimation (Schulman et al. 2016, eq. 16) with per-agent termination vs truncation.

For a rollout of ``T`` steps of many environments (any trailing batch shape, e.g. ``[E, n_agents]``)::

    delta_t = r_t + gamma * (1 - term_t) * V(s'_t) - V(s_t)
    A_t     = delta_t + gamma * lambda * (1 - term_t) * (1 - done_t) * A_{t+1},     A_T = 0
    R_t     = A_t + V(s_t)    (the value target, the reference's ``compute_returns``)

``s'_t`` is the observation that follows step t *before* any auto-reset (``info["terminal_obs"]`` when the
episode ended). ``term_t`` is the agent's OWN termination (crash, arrival, off-road): no bootstrap and the
advantage chain stops. ``done_t`` is the end of the episode (both agents terminated, or the time limit): the
chain stops because step t+1 belongs to a new episode, but a truncated agent still bootstraps from
``V(s'_t)``. Used alike for rewards and for costs (same gamma, lambda: docs/algorithms.md, MAPPO-L and MACPO).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["gae"]


def gae(reward, value, next_value, terminated, done, gamma: float, lam: float):
    """``(advantages, returns)``, both shaped like ``reward`` ``[T, ...]``.

    Args:
      reward, value, next_value: ``[T, ...]``: r_t, V(s_t), V(s'_t).
      terminated: ``[T, ...]`` bool, the agent's own termination at step t.
      done: bool broadcastable to ``reward`` (e.g. ``[T, E, 1]``): the episode ended at step t.
    """
    reward = jnp.asarray(reward)
    dt = reward.dtype
    not_term = 1.0 - jnp.asarray(terminated, dt)
    not_done = 1.0 - jnp.broadcast_to(jnp.asarray(done, dt), reward.shape)
    delta = reward + gamma * not_term * next_value - value
    carry_on = gamma * lam * not_term * not_done

    def body(a_next, x):
        d, k = x
        a = d + k * a_next
        return a, a

    _, adv = jax.lax.scan(body, jnp.zeros_like(reward[0]), (delta, carry_on), reverse=True)
    return adv, adv + value
