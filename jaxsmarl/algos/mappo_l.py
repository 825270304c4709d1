"""MAPPO-Lagrangian (Gu et al. 2023; docs/algorithms.md, MAPPO-L): the PPO-clip update of one agent on the hybrid
advantage ``A_r - lambda A_c`` with a per-minibatch projected update of the multiplier.

For ``ppo_epochs`` epochs x ``num_minibatches`` minibatches (a fresh random partition per epoch), agent i:

1. actor: ``L = -mean(factor * min(ratio A, clip(ratio, 1 +- eps) A)) - entropy_coef H`` (``H``: the Gaussian's
   entropy, or the categorical's averaged over the active samples),
   ``A = A_r - lambda_i A_c`` (no ``1 / (1 + lambda)`` normalisation), gradient-norm clip, Adam;
2. multiplier, from the same forward pass (before the actor step):
   ``lambda_i <- max(0, lambda_i + lr_lambda [(J_c - d)(1 - gamma) + mean(ratio A_c)])`` (no upper bound);
3. reward and cost critics: one clipped-Huber regression step each (:meth:`PPOBase.critic_step`).

Means run over the agent's active samples (the reference's policy active masks).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxsmarl.algos.ppo_base import PPOBase, PPOState
from jaxsmarl.gradients import gradient_update_fn
from jaxsmarl.losses import masked_mean

__all__ = ["MAPPOL", "lagrange_step"]


def lagrange_step(lam, episode_cost, cost_limit: float, gamma: float, lr: float, ratio_cost_adv):
    """``max(0, lam + lr [(J_c - d)(1 - gamma) + E(ratio A_c)])`` (§2.3 step 3)."""
    return jnp.maximum(0.0, lam + lr * ((episode_cost - cost_limit) * (1.0 - gamma) + ratio_cost_adv))


class MAPPOL(PPOBase):
    def agent_update(self, state: PPOState, i, batch, factor, key):
        cfg = self.config
        ix = self.index
        obs, action, logp_old, adv_r, adv_c, target, old_value, active = self.agent_batch(batch, i)
        jc = state.episode_cost[i]
        n = obs.shape[0]

        def minibatch(carry, idx):
            actor, a_opt, critic, c_opt, lam = carry
            o, a, lo, ar, ac, f, m = (x[idx] for x in (obs, action, logp_old, adv_r, adv_c, factor, active))

            def loss(p):
                dist = self.policy(p, o, for_update=True)
                ratio = jnp.exp(self.head.log_prob(dist, a) - lo)
                adv = ar - lam * ac
                surr = jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - cfg.clip, 1.0 + cfg.clip) * adv)
                ent = self.head.mean_entropy(dist, m)
                return -masked_mean(f * surr, m) - cfg.entropy_coef * ent, ratio

            (pl, ratio), actor, a_opt = gradient_update_fn(loss, self.actor_tx, has_aux=True)(actor, a_opt)
            ratio = jax.lax.stop_gradient(ratio)
            lam = lagrange_step(lam, jc, cfg.cost_limit, cfg.gamma, cfg.lambda_lr, masked_mean(ratio * ac, m))
            critic, c_opt, vl = self.critic_step(critic, c_opt, batch.share[idx], target[:, idx],
                                                 old_value[:, idx], m)
            return (actor, a_opt, critic, c_opt, lam), {"policy_loss": pl, "value_loss": vl,
                                                       "ratio": masked_mean(ratio, m)}

        def epoch(carry, k):
            return jax.lax.scan(minibatch, carry, self.minibatch_indices(k, n, cfg.num_minibatches))

        actor, a_opt = self.carry.pack(ix(state.actor, i), ix(state.actor_opt, i))
        carry = (actor, a_opt, *self.critics_for_loop(ix(state.critic, i), ix(state.critic_opt, i)),
                 state.lagrange[i])
        (actor, a_opt, critic, c_opt, lam), infos = jax.lax.scan(epoch, carry,
                                                                 jax.random.split(key, cfg.ppo_epochs))
        actor, a_opt = self.carry.unpack(actor, a_opt)
        critic, c_opt = self.critics_from_loop(critic, c_opt)
        st = self.set_index
        state = state.replace(actor=st(state.actor, i, actor), actor_opt=st(state.actor_opt, i, a_opt),
                              critic=st(state.critic, i, critic), critic_opt=st(state.critic_opt, i, c_opt),
                              lagrange=state.lagrange.at[i].set(lam))
        info = jax.tree.map(lambda x: jnp.mean(x, axis=(0, 1)), infos)
        info["lagrange"] = lam
        return state, info
