"""One environment step of every agent as the off-policy learners store it in their replay buffer.

The agents' observations and actions, rewards and costs, the next observation (before an automatic reset, so that
an episode's last step bootstraps from its true final state), and both ways an episode ends: an agent's own
termination and the time limit (:mod:`jaxsmarl.bootstrap` decides which of them stops bootstrapping).
"""

from __future__ import annotations

import flax.struct
import jax

__all__ = ["MaskedTransition", "Transition"]


@flax.struct.dataclass
class Transition:
    obs: jax.Array  # [n_agents, obs_dim]
    action: jax.Array  # executed actions: int32 [n_agents] (discrete) or [n_agents, action_dim] (continuous)
    reward: jax.Array  # [n_agents]
    cost: jax.Array  # [n_agents]
    next_obs: jax.Array  # [n_agents, obs_dim] (pre-reset observation at episode ends)
    terminated: jax.Array  # bool [n_agents], per-agent terminal flag (not the time limit)
    truncated: jax.Array  # bool [], time limit reached


@flax.struct.dataclass
class MaskedTransition(Transition):
    active: jax.Array  # bool [n_agents]: the agent drives in this episode (absent agents are left out of its loss)
