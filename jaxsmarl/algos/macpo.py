"""MACPO (Gu et al. 2023; docs/algorithms.md, MACPO): a constrained trust-region step of one agent per minibatch.

For each of ``num_minibatches`` minibatches (one pass, no epochs), agent i:

1. reward and cost critics: one clipped-Huber regression step each;
2. ``c = (J_c - d)(1 - gamma)`` (``0 -> 1e-8``);
3. ``g = grad[-mean(ratio factor A_r)]``, ``b = grad mean(ratio factor A_c)`` w.r.t. the flat actor parameters
   (the network, and ``log_std`` of a Gaussian policy);
4. ``H^-1 g``, ``H^-1 b`` by conjugate gradient with products by the Hessian of the mean KL at the current
   parameters (damping 0.1), computed as ``J^T H_out J`` (:func:`jaxsmarl.cpo.gauss_newton_operator`: the same
   matrix, cheaper than differentiating the KL's gradient forward-mode; on XLA:CPU the
   ``J^T`` products make their weight gradients from transposed layer inputs, :func:`jaxsmarl.mlp.mlp_rows`);
5. the CPO direction (:func:`jaxsmarl.cpo.cpo_direction`);
6. the line search (:func:`jaxsmarl.cpo.line_search`): accept a candidate if ``KL < delta``, the reward loss
   improved (only when ``optim_case > 1``) and the cost surrogate grew by at most ``max(-c, 0)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from jaxsmarl import cpo
from jaxsmarl.algos.ppo_base import PPOBase, PPOState
from jaxsmarl.losses import masked_mean

__all__ = ["MACPO"]


class MACPO(PPOBase):
    def cpo_step(self, actor, o, a, lo, ar, ac, f, m, jc):
        """One CPO update of an actor on a minibatch: ``(new actor, info)``."""
        cfg = self.config
        theta, unravel = ravel_pytree(actor)

        head = self.head
        policy_at = lambda th: self.policy(unravel(th), o)  # (mean [B, k], std [k]) or logits [B, A]

        def policy_rev(th):
            """``policy_at`` for reverse mode replayed at one point (``Network.apply_replay``; in the column
            layout with the weight gradients taken from transposed layer inputs made once per step,
            :func:`jaxsmarl.mlp.mlp_rows`): the gradients below and the ``J^T`` of the Fisher products
            (:func:`cpo.gauss_newton_operator`)."""
            act = unravel(th)
            return head.dist(act, self.actor_net.apply_replay(act["net"], o))

        def surrogates_of(out):
            ratio = jnp.exp(head.log_prob(out, a) - lo)
            return -masked_mean(ratio * f * ar, m), masked_mean(ratio * f * ac, m)

        # both gradients from one forward pass
        (reward_loss, cost_loss), pullback = jax.vjp(lambda th: surrogates_of(policy_rev(th)), theta)
        one, zero = jnp.ones_like(reward_loss), jnp.zeros_like(reward_loss)
        (g,), (b,) = pullback((one, zero)), pullback((zero, one))
        old = jax.lax.stop_gradient(policy_at(theta))

        def kl_of(out):
            return masked_mean(head.kl(old, out), m)

        # the KL's Hessian at theta, J^T H_out J (the Fisher matrix; see cpo.gauss_newton_operator)
        fvp = cpo.gauss_newton_operator(policy_at, kl_of, theta, cfg.fvp_damping, reverse_fn=policy_rev)
        hinv_g = cpo.conjugate_gradient(fvp, g, cfg.cg_iters)
        hinv_b = cpo.conjugate_gradient(fvp, b, cfg.cg_iters)
        c = (jc - cfg.cost_limit) * (1.0 - cfg.gamma)
        c = jnp.where(c == 0, 1e-8, c)
        x, case, lam, nu = cpo.cpo_direction(g, b, hinv_g, hinv_b, c, cfg.kl_threshold)

        def evaluate(th):
            out = policy_at(th)
            r_new, c_new = surrogates_of(out)
            return {"reward_loss": r_new, "cost_loss": c_new, "kl": kl_of(out)}

        def accept(s):
            improve = jnp.where(case > 1, s["reward_loss"] - reward_loss < 0, True)
            return (s["kl"] < cfg.kl_threshold) & improve & (s["cost_loss"] - cost_loss <= jnp.maximum(-c, 0.0))

        theta_new, found, idx, stats = cpo.line_search(theta, x, evaluate, accept, cfg.ls_steps, cfg.ls_fraction,
                                                       cfg.fraction_coef)
        info = {"case": jax.nn.one_hot(case, 5, dtype=theta.dtype), "accepted": found.astype(theta.dtype),
                "kl": jnp.where(found, stats["kl"][idx], 0.0), "reward_loss": reward_loss}
        return unravel(theta_new), info

    def agent_update(self, state: PPOState, i, batch, factor, key):
        cfg = self.config
        ix = self.index
        obs, action, logp_old, adv_r, adv_c, target, old_value, active = self.agent_batch(batch, i)
        jc = state.episode_cost[i]

        def minibatch(carry, idx):
            actor, critic, c_opt = carry
            critic, c_opt, vl = self.critic_step(critic, c_opt, batch.share[idx], target[:, idx],
                                                 old_value[:, idx], active[idx])
            actor, info = self.cpo_step(actor, *(x[idx] for x in (obs, action, logp_old, adv_r, adv_c, factor,
                                                                  active)), jc)
            info["value_loss"] = vl
            return (actor, critic, c_opt), info

        idxs = self.minibatch_indices(key, obs.shape[0], cfg.num_minibatches)
        (actor, critic, c_opt), infos = jax.lax.scan(
            minibatch, (ix(state.actor, i), *self.critics_for_loop(ix(state.critic, i), ix(state.critic_opt, i))),
            idxs)
        critic, c_opt = self.critics_from_loop(critic, c_opt)
        st = self.set_index
        state = state.replace(actor=st(state.actor, i, actor), critic=st(state.critic, i, critic),
                              critic_opt=st(state.critic_opt, i, c_opt))
        return state, jax.tree.map(lambda x: jnp.mean(x, axis=0), infos)
