"""The policy heads of MAPPO-L and MACPO: what turns an actor network's output into an action distribution
(docs/algorithms.md, MAPPO-L and MACPO; discrete actions and K agents).

:class:`GaussianHead` (continuous actions): the output is the mean, the bounded standard deviation a state-free
parameter ``log_std`` (:mod:`jaxsmarl.gaussian`). :class:`CategoricalHead` (discrete actions): the output is the
logits (:mod:`jaxsmarl.categorical`). Both offer the same methods, so the algorithms never ask which one they
hold; :func:`policy_head` picks one from the action space, the only place that does.

A distribution ``dist`` is a pytree: ``(mean [..., k], std [k])`` or ``logits [..., A]``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxsmarl.categorical import categorical_entropy, categorical_kl, categorical_log_prob
from jaxsmarl.gaussian import gaussian_entropy, gaussian_kl, gaussian_log_prob, std_from_param
from jaxsmarl.losses import masked_mean

__all__ = ["GaussianHead", "CategoricalHead", "policy_head"]


class GaussianHead:
    """Diagonal Gaussian over ``action_dim`` unbounded actions (the env clips them to [-1, 1])."""

    agent_axes = (1, 0)  # where vmapping over agents puts the agent axis: mean [B, N, k], std [N, k]

    def __init__(self, action_dim: int, std_x_coef: float, std_y_coef: float):
        self.out_dim = action_dim
        self.x_coef, self.y_coef = std_x_coef, std_y_coef

    def init(self, dtype) -> dict:
        """The actor's parameters besides the network: ``log_std`` starts at ``std_x_coef``."""
        return {"log_std": jnp.full((self.out_dim,), self.x_coef, dtype)}

    def dist(self, actor, out):
        return out, std_from_param(actor["log_std"], self.x_coef, self.y_coef)

    def sample(self, key, dist):
        mean, std = dist
        return mean + std * jax.random.normal(key, mean.shape, mean.dtype)

    def log_prob(self, dist, action):
        mean, std = dist
        return gaussian_log_prob(action, mean, std)

    def mean_entropy(self, dist, mask):
        """The entropy (state-free: the same for every sample, so ``mask`` does not matter)."""
        del mask
        return gaussian_entropy(dist[1])

    def kl(self, old, new):
        """Per-sample ``KL(old || new)``."""
        (mean_old, std_old), (mean, std) = old, new
        return gaussian_kl(mean_old, std_old, mean, jnp.broadcast_to(std, mean.shape))

    def greedy(self, dist):
        return jnp.clip(dist[0], -1.0, 1.0)

    def env_action(self, action):
        return jnp.clip(action, -1.0, 1.0)


class CategoricalHead:
    """Categorical over ``num_actions`` discrete actions; the actor's output is its logits."""

    agent_axes = 1  # logits [B, N, A]

    def __init__(self, num_actions: int):
        self.out_dim = num_actions

    def init(self, dtype) -> dict:
        del dtype
        return {}

    def dist(self, actor, out):
        del actor
        return out

    def sample(self, key, dist):
        return jax.random.categorical(key, dist, axis=-1).astype(jnp.int32)

    def log_prob(self, dist, action):
        return categorical_log_prob(action, dist)

    def mean_entropy(self, dist, mask):
        """The entropy averaged over the samples where ``mask``."""
        return masked_mean(categorical_entropy(dist), mask)

    def kl(self, old, new):
        return categorical_kl(old, new)

    def greedy(self, dist):
        return jnp.argmax(dist, axis=-1).astype(jnp.int32)

    def env_action(self, action):
        return action


def policy_head(action_dim: int, num_actions: int, std_x_coef: float, std_y_coef: float):
    """The head for the action space: categorical when ``num_actions > 0`` (discrete), else Gaussian."""
    if num_actions < 0 or (num_actions == 0 and action_dim < 1):
        raise ValueError(f"a policy needs num_actions >= 1 (discrete) or action_dim >= 1 (continuous), got "
                         f"num_actions={num_actions}, action_dim={action_dim}")
    if num_actions > 0:
        return CategoricalHead(num_actions)
    return GaussianHead(action_dim, std_x_coef, std_y_coef)
