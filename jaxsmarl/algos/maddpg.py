"""Constrained Stackelberg MADDPG (CS-MADDPG, paper Algorithm 2, eqs. p19-p26) and its MADDPG relatives.

Two agents, deterministic actors bounded by ``max_action * tanh``:

* leader ``a1 = mu1(o1)``, follower ``a2 = mu2(o2, a1)`` (decided in order, executed together); with
  ``stackelberg=False`` (plain MADDPG) ``a2 = mu2(o2)``.
* per agent a centralized reward critic ``Q_i(s, a1, a2)`` and (``constrained=True``) cost critic
  ``G_i(s, a1, a2)``, stacked as ``[2 agents, K kinds]`` (acting and evaluation: batched einsums over the
  stack; the update: the networks' ``apply_update``, in the column layout each network alone,
  :mod:`jaxsmarl.network`).
  ``critic_input="joint"``: ``s = [o1, o2]`` (paper: the global state); ``"own"``: ``s = o_i`` (the authors'
  critics, docs/algorithms.md).
* Critic targets (Alg. 2, critic / cost-critic updates): ``y_i = r_i + gamma (1 - t_i) Q_i^targ(s', a1', a2')``,
  ``g_i = c_i + gamma (1 - t_i) G_i^targ(s', a1', a2')`` with ``a1' = mu1^targ(o1')``, ``a2' = mu2^targ(o2', a1')``.
  Algorithm 2 prints ``a1' = mu1(s)``; we use the target actors at s', as the paper's text equations and the
  authors' code do. ``t_i`` is agent i's OWN termination (``bootstrap_on_truncation=False`` adds the time limit,
  as the authors' stored ``done``).
* Actors (p21, p23, p25): leader loss ``mean_B[-Q1(s, a1, a2) + pen_1(G1(s, a1, a2))]`` with ``a1 = mu1(o1)``,
  ``a2 = mu2(o2, a1)``, differentiated w.r.t. theta1 THROUGH the follower's actor (the Stackelberg total
  derivative of p23; only theta1 is stepped). Follower loss the same with Q2/G2, differentiated w.r.t. theta2
  through a2 only (p25). ``pen_i`` is the Lagrangian term of :class:`jaxsmarl.lagrangian.Lagrangian`.
* Multipliers (p22b/p22d): one per agent, from the batch cost estimates at the current actors' actions.
* Exploration (authors, §5.1): with probability ``eps_i`` a uniform action, else ``clip(mu_i + noise_i N(0, 1))``;
  the follower responds to the EXECUTED leader action. ``eps`` and ``noise`` decay linearly per env step.
* One update = one gradient step of every network from the same parameters (critics and actors together, the
  actors on the pre-step critics, as the authors' actor-then-critic order), the multiplier step, and the
  authors' periodic soft target update of all networks (``tau`` every ``target_update_every`` updates).

Differences to the authors' code, as options: ``lambda_rule="authors"`` (non-decreasing lambda and hinge
penalty), ``critic_input="own"``, ``bootstrap_on_truncation=False``, ``actor_order="sequential"`` (their
``leader.train()`` runs before ``follower.train()``, so the follower's actor loss and multiplier see the leader
actor after its step; by default both actors step from the same parameters, as Algorithm 2 reads),
``terminal_mask="batch_mean"`` (their targets bootstrap every transition with the discount scaled by the
batch's done fraction, :mod:`jaxsmarl.bootstrap`).
"""

from __future__ import annotations

from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import optax

from jaxsmarl import bootstrap, networks
from jaxsmarl.actor import Actor, actor_columns, make_actor
from jaxsmarl.algos.maddpg_config import MADDPGConfig
from jaxsmarl.exploration import linear_decay
from jaxsmarl.lagrangian import Lagrangian
from jaxsmarl.networks import critic_values, critic_values_columns, layer_name
from jaxsmarl.transition import Transition

__all__ = ["MADDPGConfig", "MADDPGState", "MADDPGAgent", "Actor", "Transition", "critic_values",
           "critic_values_columns", "actor_columns"]

Q, G = 0, 1  # kind axis of the stacked critics
LEADER, FOLLOWER = 0, 1


@flax.struct.dataclass
class MADDPGState:
    actors: Any  # (leader params, follower params)
    critics: Any  # stacked [2, K, ...]
    target_actors: Any
    target_critics: Any
    actor_opt: Any
    critic_opt: Any
    lam: jax.Array  # [2] Lagrange multipliers (unused when unconstrained)
    n_updates: jax.Array  # int32


class MADDPGAgent:
    """The MADDPG family as pure functions over :class:`MADDPGState` (jit/vmap them freely)."""

    Transition = Transition

    def __init__(self, config: MADDPGConfig):
        c = self.config = config
        # the leader's and the follower's actor: one module, two input sizes
        self.actor_nets = (make_actor(c.obs_dim, c.hidden_sizes, c.action_dim, c.max_action, c.init),
                           make_actor(c.follower_in_dim, c.hidden_sizes, c.action_dim, c.max_action, c.init))
        self.actor = self.actor_nets[LEADER]  # its apply serves either actor
        self.critic = networks.JointActionMLP(hidden=tuple(c.hidden_sizes), init_scheme=c.init)  # one network
        self.critic_stack = networks.make_critic_stack(c.critic_obs_dim, (c.action_dim, c.action_dim),
                                                       c.hidden_sizes, c.init, shape=(2, c.n_kinds))
        self.actor_opt = optax.adam(c.lr_actor)
        self.critic_opt = optax.adam(c.lr_critic)
        self.lagrangian = Lagrangian(tuple(c.cost_threshold), c.lr_lambda, c.lambda_max, c.lambda_init,
                                     c.lambda_rule)

    # ---------------------------------------------------------------------------------------------
    def init(self, key: jax.Array) -> MADDPGState:
        """Online networks, identical target copies (Alg. 2 initialisation), Adam states, lambda_init."""
        k_crit, k_lead, k_fol = jax.random.split(key, 3)
        critics = self.critic_stack.init(k_crit)
        actors = (self.actor_nets[LEADER].init(k_lead), self.actor_nets[FOLLOWER].init(k_fol))
        return MADDPGState(actors=actors, critics=critics, target_actors=actors, target_critics=critics,
                           actor_opt=self.actor_opt.init(actors), critic_opt=self.critic_opt.init(critics),
                           lam=self.lagrangian.init(), n_updates=jnp.int32(0))

    def transition_example(self) -> Transition:
        c = self.config
        return Transition(obs=jnp.zeros((2, c.obs_dim)), action=jnp.zeros((2, c.action_dim)),
                          reward=jnp.zeros((2,)), cost=jnp.zeros((2,)), next_obs=jnp.zeros((2, c.obs_dim)),
                          terminated=jnp.zeros((2,), bool), truncated=jnp.zeros((), bool))

    # ---------------------------------------------------------------------------------------------
    def _actor(self, who: int, actor_params, x: jax.Array, for_update: bool = False) -> jax.Array:
        net = self.actor_nets[who]
        return (net.apply_update if for_update else net.apply)(actor_params, x)

    def leader_action(self, actor_params, obs_leader: jax.Array, for_update: bool = False) -> jax.Array:
        """``mu1(o1)``: ``[..., obs_dim]`` -> ``[..., action_dim]``. ``for_update=True`` (a ``[B, obs_dim]``
        batch): the same actor in the form the gradient steps differentiate (``Network.apply_update``)."""
        return self._actor(LEADER, actor_params, obs_leader, for_update)

    def follower_action(self, actor_params, obs_follower: jax.Array, a1: jax.Array, for_update: bool = False):
        """``mu2(o2, a1)`` (Stackelberg) or ``mu2(o2)`` (plain MADDPG)."""
        x = jnp.concatenate([obs_follower, a1], axis=-1) if self.config.stackelberg else obs_follower
        return self._actor(FOLLOWER, actor_params, x, for_update)

    def joint_action(self, actors, obs: jax.Array) -> jax.Array:
        """Greedy hierarchical decision ``[..., 2, D]`` -> ``[..., 2, action_dim]``."""
        a1 = self.leader_action(actors[LEADER], obs[..., LEADER, :])
        a2 = self.follower_action(actors[FOLLOWER], obs[..., FOLLOWER, :], a1)
        return jnp.stack([a1, a2], axis=-2)

    def greedy_preactivations(self, actors, obs: jax.Array) -> jax.Array:
        """The greedy decision's actor outputs before ``max_action * tanh``, ``[..., 2, action_dim]``. Where
        ``|x| >> 1`` the actor is saturated: ``tanh'(x) ~ 0`` passes almost no gradient back to it, a known way
        for DDPG to get stuck (``benchmarks/actor_saturation.py``)."""
        last = layer_name(len(self.config.hidden_sizes))

        def pre(params, x):
            _, st = self.actor.apply(params, x, capture_intermediates=lambda mdl, _: mdl.name == last)
            return st["intermediates"][last]["__call__"][0]

        a1 = self.leader_action(actors[LEADER], obs[..., LEADER, :])
        x2 = (jnp.concatenate([obs[..., FOLLOWER, :], a1], axis=-1) if self.config.stackelberg
              else obs[..., FOLLOWER, :])
        return jnp.stack([pre(actors[LEADER], obs[..., LEADER, :]), pre(actors[FOLLOWER], x2)], axis=-2)

    def critic_input(self, obs: jax.Array, a1: jax.Array, a2: jax.Array) -> jax.Array:
        """Per-agent critic inputs ``[B, 2, D_in]``: ``[s, a1, a2]`` with ``s = [o1, o2]`` or ``o_i``."""
        b = obs.shape[0]
        acts = jnp.concatenate([a1, a2], axis=-1)
        if self.config.critic_input == "joint":
            x = jnp.concatenate([obs.reshape((b, -1)), acts], axis=-1)
            return jnp.broadcast_to(x[:, None], (b, 2, x.shape[-1]))
        return jnp.concatenate([obs, jnp.broadcast_to(acts[:, None], (b, 2, acts.shape[-1]))], axis=-1)

    def values(self, critics, obs: jax.Array, actions: jax.Array, for_update: bool = False) -> jax.Array:
        """Critics at given joint actions: obs ``[B, 2, D]``, actions ``[B, 2, k]`` -> ``[B, 2, K]``
        (``for_update=True``: the same values in the form the update uses, ``Network.apply_update``)."""
        x = self.critic_input(obs, actions[:, LEADER], actions[:, FOLLOWER])
        return (self.critic_stack.apply_update if for_update else self.critic_stack.apply)(critics, x)

    # ---------------------------------------------------------------------------------------------
    def exploration(self, env_step: jax.Array) -> dict:
        """``{"eps": [2], "noise": [2]}`` after ``env_step`` steps: ``max(min, start - decay * step)``."""
        c = self.config
        return {"eps": linear_decay(c.eps_start, c.eps_min, c.explore_decay, env_step),
                "noise": linear_decay(c.noise_start, c.noise_min, c.explore_decay, env_step)}

    def _explore(self, mu: jax.Array, key: jax.Array, eps: jax.Array, noise: jax.Array) -> jax.Array:
        m = self.config.max_action
        k_coin, k_unif, k_norm = jax.random.split(key, 3)
        coin = jax.random.uniform(k_coin, mu.shape[:-1] + (1,)) < eps
        unif = jax.random.uniform(k_unif, mu.shape, mu.dtype, -m, m)
        noisy = jnp.clip(mu + noise * jax.random.normal(k_norm, mu.shape, mu.dtype), -m, m)
        return jnp.where(coin, unif, noisy)

    def act(self, state: MADDPGState, obs: jax.Array, key: jax.Array, explore: dict) -> jax.Array:
        """Exploring actions ``[..., 2, k]``; the follower responds to the executed (noisy) leader action."""
        k1, k2 = jax.random.split(key)
        eps, noise = explore["eps"], explore["noise"]
        a1 = self._explore(self.leader_action(state.actors[LEADER], obs[..., LEADER, :]), k1, eps[0], noise[0])
        a2 = self.follower_action(state.actors[FOLLOWER], obs[..., FOLLOWER, :], a1)
        a2 = self._explore(a2, k2, eps[1], noise[1])
        return jnp.stack([a1, a2], axis=-2)

    def greedy_act(self, state: MADDPGState, obs: jax.Array) -> jax.Array:
        return self.joint_action(state.actors, obs)

    # ---------------------------------------------------------------------------------------------
    def td_targets(self, state: MADDPGState, batch: Transition) -> jax.Array:
        """``[B, 2, K]``: ``(r_i, c_i) + gamma (1 - t_i) (Q_i^targ, G_i^targ)(s', mu^targ(s'))``."""
        c = self.config
        a_next = self.joint_action(state.target_actors, batch.next_obs)
        boot = self.values(state.target_critics, batch.next_obs, a_next, for_update=True)
        rc = jnp.stack([batch.reward, batch.cost][: c.n_kinds], axis=-1)
        keep = bootstrap.continuation(batch.terminated, batch.truncated, c.terminal_mask, c.bootstrap_on_truncation,
                                      rc.dtype)
        return rc + c.gamma * keep[..., None] * boot

    def actor_values(self, actors, critics, obs: jax.Array, through_follower: bool | None = None) -> jax.Array:
        """Each agent's critics at the current actors' actions, wired for the actor gradients: ``[B, 2, K]``.

        Row 0 (leader) is ``Q1/G1(s, a1, mu2(o2, a1))`` with ``a1 = mu1(o1)``; gradients reach theta1 through a1
        directly and, if ``through_follower`` (default: ``stackelberg``), through the follower's actor (p23);
        theta2 is held fixed there. Row 1 (follower) is ``Q2/G2(s, a1, mu2(o2, a1))`` with a1 held fixed, so its
        gradient reaches theta2 through a2 only (p25). Critic parameters are held fixed in both rows.
        """
        through = self.config.stackelberg if through_follower is None else through_follower
        critics = jax.lax.stop_gradient(critics)
        a1 = self.leader_action(actors[LEADER], obs[:, LEADER], for_update=True)
        a1_fixed = jax.lax.stop_gradient(a1)
        a2_lead = self.follower_action(jax.lax.stop_gradient(actors[FOLLOWER]), obs[:, FOLLOWER],
                                       a1 if through else a1_fixed, for_update=True)
        a2_fol = self.follower_action(actors[FOLLOWER], obs[:, FOLLOWER], a1_fixed, for_update=True)
        x_lead = self.critic_input(obs, a1, a2_lead)[:, LEADER]
        x_fol = self.critic_input(obs, a1_fixed, a2_fol)[:, FOLLOWER]
        x = jnp.stack([x_lead, x_fol], axis=1)
        return self.critic_stack.apply_update(critics, x)

    def actor_losses(self, actors, critics, lam: jax.Array, obs: jax.Array, through_follower: bool | None = None):
        """``([2] per-agent losses mean_B(-Q_i + pen_i(G_i)), [B, 2, K] values)``; minimising loss i over
        theta_i is the ascent of p22a/p22c."""
        v = self.actor_values(actors, critics, obs, through_follower)
        per_sample = -v[..., Q]
        if self.config.constrained:
            per_sample = per_sample + self.lagrangian.penalty(lam, v[..., G])
        return jnp.mean(per_sample, axis=0), v

    def _loss(self, params, state: MADDPGState, batch: Transition, targets: jax.Array):
        critics, actors = params
        pred = self.values(critics, batch.obs, batch.action, for_update=True)
        per_net = jnp.mean((pred - jax.lax.stop_gradient(targets)) ** 2, axis=0)  # [2, K]
        actor_loss, v = self.actor_losses(actors, critics, state.lam, batch.obs)
        return jnp.sum(per_net) + jnp.sum(actor_loss), (per_net, jnp.mean(pred, axis=0), actor_loss, v)

    def update(self, state: MADDPGState, batch: Transition, key: jax.Array, explore: Any = None):
        """One step of all critics and actors, the multipliers and the periodic soft target update."""
        del key, explore  # deterministic given the batch
        c = self.config
        targets = self.td_targets(state, batch)
        grads, (per_net, mean_pred, actor_loss, v) = jax.grad(self._loss, has_aux=True)(
            (state.critics, state.actors), state, batch, targets)
        g_crit, g_act = grads
        upd, critic_opt = self.critic_opt.update(g_crit, state.critic_opt, state.critics)
        critics = optax.apply_updates(state.critics, upd)
        upd, actor_opt = self.actor_opt.update(g_act, state.actor_opt, state.actors)
        actors = optax.apply_updates(state.actors, upd)
        if c.actor_order == "sequential":
            # the authors' leader.train() before follower.train(): the follower's actor loss (and its multiplier)
            # at a1 = mu1(o1) of the STEPPED leader actor. Adam is elementwise, so the leader's step stands.
            def follower_loss(theta2):
                loss, v_new = self.actor_losses((actors[LEADER], theta2), state.critics, state.lam, batch.obs)
                return loss[FOLLOWER], (loss, v_new)

            g2, (loss_new, v_new) = jax.grad(follower_loss, has_aux=True)(state.actors[FOLLOWER])
            upd, actor_opt = self.actor_opt.update((g_act[LEADER], g2), state.actor_opt, state.actors)
            actors = optax.apply_updates(state.actors, upd)
            v = v.at[:, FOLLOWER].set(v_new[:, FOLLOWER])
            actor_loss = actor_loss.at[FOLLOWER].set(loss_new[FOLLOWER])
        lam = self.lagrangian.update(state.lam, v[..., G]) if c.constrained else state.lam

        n = state.n_updates  # the authors soft-update when train_step > 0 and train_step % update_rate == 0
        do_soft = (n > 0) & (n % c.target_update_every == 0)
        pick = lambda new, old: jax.tree.map(lambda s, t: jnp.where(do_soft, s, t), new, old)
        target_critics = pick(networks.soft_update(state.target_critics, critics, c.tau), state.target_critics)
        target_actors = pick(networks.soft_update(state.target_actors, actors, c.tau), state.target_actors)
        info = {"loss_q": per_net[:, Q], "q_mean": mean_pred[:, Q], "actor_loss": actor_loss}
        if c.constrained:
            info.update(loss_g=per_net[:, G], g_mean=mean_pred[:, G], g_actor=jnp.mean(v[..., G], axis=0), lam=lam)
        new = MADDPGState(actors=actors, critics=critics, target_actors=target_actors,
                          target_critics=target_critics, actor_opt=actor_opt, critic_opt=critic_opt, lam=lam,
                          n_updates=n + 1)
        return new, info
