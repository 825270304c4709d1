"""Constrained Stackelberg MADDPG (CS-MADDPG, paper Algorithm 2, eqs. p19-p26) and its MADDPG relatives.

Two agents, deterministic actors bounded by ``max_action * tanh``:

* leader ``a1 = mu1(o1)``, follower ``a2 = mu2(o2, a1)`` (decided in order, executed together); with
  ``stackelberg=False`` (plain MADDPG) ``a2 = mu2(o2)``.
* per agent a centralized reward critic ``Q_i(s, a1, a2)`` and (``constrained=True``) cost critic
  ``G_i(s, a1, a2)``, stacked as ``[agents, kinds]`` (acting and evaluation: batched einsums over the
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
* K agents and any hierarchy (``n_agents``, ``hierarchy``, :mod:`jaxsmarl.hierarchy`; the paper's multi-agent
  expansion, docs/algorithms.md): each actor reads its own observation and the actions of every agent on the
  levels above it, ``a_i = mu_i(o_i, a_above(i))``; the levels decide in order, the agents of one level
  simultaneously. The critics read the joint observation (or ``o_i``) and all K actions. Agent i's actor loss
  is the two-agent one with ``Q_i/G_i`` at the hierarchical decision, differentiated w.r.t. theta_i through a_i
  and through the actors of every level below it (each lower action a function of a_i and of the lower actions
  between them: the chain rule of p23 over the whole hierarchy), the levels above and its own level held
  fixed (:meth:`MADDPGAgent.actor_values`). The two-agent chain ``0|1`` is the leader/follower case above;
  ``stackelberg=False`` (MADDPG, C-MADDPG) puts every agent on one level: each actor on its own observation,
  its gradient through its own action only.
* Multipliers (p22b/p22d): one per agent, from the batch cost estimates at the current actors' actions.
* Exploration (authors, §5.1): with probability ``eps_i`` a uniform action, else ``clip(mu_i + noise_i N(0, 1))``;
  the follower responds to the EXECUTED leader action. ``eps`` and ``noise`` decay linearly per env step.
* One update = one gradient step of every network from the same parameters (critics and actors together, the
  actors on the pre-step critics, as the authors' actor-then-critic order), the multiplier step, and the
  authors' periodic soft target update of all networks (``tau`` every ``target_update_every`` updates).

Differences to the authors' code, as options: ``lambda_rule="authors"`` (non-decreasing lambda and hinge
penalty), ``critic_input="own"``, ``bootstrap_on_truncation=False``, ``actor_order="sequential"`` (their
``leader.train()`` runs before ``follower.train()``, so the follower's actor loss and multiplier see the leader
actor after its step; with K agents one agent after another in decision order, the agents of one level too, so the
flat C-MADDPG's agent 1 sees agent 0's stepped actor; by default all actors step from the same parameters, as
Algorithm 2 reads),
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
from jaxsmarl.hierarchy import agent_order
from jaxsmarl.lagrangian import Lagrangian
from jaxsmarl.networks import critic_values, critic_values_columns, layer_name
from jaxsmarl.transition import Transition

__all__ = ["MADDPGConfig", "MADDPGState", "MADDPGAgent", "Actor", "Transition", "critic_values",
           "critic_values_columns", "actor_columns"]

Q, G = 0, 1  # kind axis of the stacked critics


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
        self.n = c.n_agents
        self.levels = c.levels
        # one actor per agent: one module, input sizes by the agent's level
        self.actor_nets = tuple(make_actor(c.actor_in_dim(i), c.hidden_sizes, c.action_dim, c.max_action, c.init)
                                for i in range(self.n))
        self.actor = self.actor_nets[0]  # its apply serves every actor
        self.critic = networks.JointActionMLP(hidden=tuple(c.hidden_sizes), init_scheme=c.init)  # one network
        self.critic_stack = networks.make_critic_stack(c.critic_obs_dim, (c.action_dim,) * self.n,
                                                       c.hidden_sizes, c.init, shape=(self.n, c.n_kinds))
        self.actor_opt = optax.adam(c.lr_actor)
        self.critic_opt = optax.adam(c.lr_critic)
        self.lagrangian = Lagrangian(tuple(c.cost_threshold), c.lr_lambda, c.lambda_max, c.lambda_init,
                                     c.lambda_rule)

    # ---------------------------------------------------------------------------------------------
    def init(self, key: jax.Array) -> MADDPGState:
        """Online networks, identical target copies (Alg. 2 initialisation), Adam states, lambda_init."""
        k_crit, *k_actors = jax.random.split(key, 1 + self.n)  # critics, then each agent's actor
        critics = self.critic_stack.init(k_crit)
        actors = tuple(net.init(k) for net, k in zip(self.actor_nets, k_actors))
        return MADDPGState(actors=actors, critics=critics, target_actors=actors, target_critics=critics,
                           actor_opt=self.actor_opt.init(actors), critic_opt=self.critic_opt.init(critics),
                           lam=self.lagrangian.init(), n_updates=jnp.int32(0))

    def transition_example(self) -> Transition:
        c = self.config
        k = c.n_agents
        return Transition(obs=jnp.zeros((k, c.obs_dim)), action=jnp.zeros((k, c.action_dim)),
                          reward=jnp.zeros((k,)), cost=jnp.zeros((k,)), next_obs=jnp.zeros((k, c.obs_dim)),
                          terminated=jnp.zeros((k,), bool), truncated=jnp.zeros((), bool))

    # ---------------------------------------------------------------------------------------------
    def _actor(self, who: int, actor_params, x: jax.Array, for_update: bool = False) -> jax.Array:
        net = self.actor_nets[who]
        return (net.apply_update if for_update else net.apply)(actor_params, x)

    def actor_input(self, who: int, obs_who: jax.Array, actions: dict) -> jax.Array:
        """Agent ``who``'s actor input: its observation ``[..., obs_dim]`` and the actions ``actions[j]`` of the
        agents on the levels above it, in decision order (none for the first level)."""
        above = self.config.above(who)
        return jnp.concatenate([obs_who] + [actions[j] for j in above], axis=-1) if above else obs_who

    def action(self, who: int, actor_params, obs_who: jax.Array, actions: dict, for_update: bool = False):
        """``mu_who(o_who, a_above)``: ``[..., action_dim]``. ``for_update=True`` (a ``[B, ...]`` batch): the same
        actor in the form the gradient steps differentiate (``Network.apply_update``)."""
        return self._actor(who, actor_params, self.actor_input(who, obs_who, actions), for_update)

    def _decide(self, actors, obs: jax.Array, respond=None) -> dict:
        """Every agent's action, level by level: ``{agent: [..., action_dim]}``; ``respond(who, mu)`` (exploration)
        turns an actor's output into the executed action that the levels below read."""
        acts: dict = {}
        for level in self.levels:
            for i in level:
                mu = self.action(i, actors[i], obs[..., i, :], acts)
                acts[i] = mu if respond is None else respond(i, mu)
        return acts

    def joint_action(self, actors, obs: jax.Array) -> jax.Array:
        """Greedy hierarchical decision ``[..., K, D]`` -> ``[..., K, action_dim]``."""
        acts = self._decide(actors, obs)
        return jnp.stack([acts[i] for i in range(self.n)], axis=-2)

    def greedy_preactivations(self, actors, obs: jax.Array) -> jax.Array:
        """The greedy decision's actor outputs before ``max_action * tanh``, ``[..., K, action_dim]``. Where
        ``|x| >> 1`` the actor is saturated: ``tanh'(x) ~ 0`` passes almost no gradient back to it, a known way
        for DDPG to get stuck (``benchmarks/actor_saturation.py``)."""
        last = layer_name(len(self.config.hidden_sizes))

        def pre(params, x):
            _, st = self.actor.apply(params, x, capture_intermediates=lambda mdl, _: mdl.name == last)
            return st["intermediates"][last]["__call__"][0]

        acts = self._decide(actors, obs)
        return jnp.stack([pre(actors[i], self.actor_input(i, obs[..., i, :], acts)) for i in range(self.n)], axis=-2)

    def critic_input(self, obs: jax.Array, *actions: jax.Array) -> jax.Array:
        """Per-agent critic inputs ``[B, K, D_in]``: ``[s, a_1, ..., a_K]`` with ``s`` the joint observation or
        ``o_i``; ``actions``: one ``[B, action_dim]`` per agent, in agent order."""
        b = obs.shape[0]
        k = len(actions)
        acts = jnp.concatenate(actions, axis=-1)
        if self.config.critic_input == "joint":
            x = jnp.concatenate([obs.reshape((b, -1)), acts], axis=-1)
            return jnp.broadcast_to(x[:, None], (b, k, x.shape[-1]))
        return jnp.concatenate([obs, jnp.broadcast_to(acts[:, None], (b, k, acts.shape[-1]))], axis=-1)

    def values(self, critics, obs: jax.Array, actions: jax.Array, for_update: bool = False) -> jax.Array:
        """Critics at given joint actions: obs ``[B, K, D]``, actions ``[B, K, k]`` -> ``[B, K, kinds]``
        (``for_update=True``: the same values in the form the update uses, ``Network.apply_update``)."""
        x = self.critic_input(obs, *[actions[:, i] for i in range(self.n)])
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
        """Exploring actions ``[..., K, k]``; each level responds to the executed (noisy) actions of the levels
        above it."""
        keys = tuple(jax.random.split(key, self.n))
        eps, noise = explore["eps"], explore["noise"]
        acts = self._decide(state.actors, obs, lambda i, mu: self._explore(mu, keys[i], eps[i], noise[i]))
        return jnp.stack([acts[i] for i in range(self.n)], axis=-2)

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
        """Each agent's critics at the current actors' actions, wired for the actor gradients: ``[B, K, kinds]``.

        Row i is ``Q_i/G_i(s, a)`` at the hierarchical decision ``a``. Agent i's action ``a_i = mu_i(o_i, a_above)``
        is live in theta_i; the agents before it in decision order keep their actions; the agents after it respond
        through their actors (parameters held fixed), in decision order, so the gradient reaches theta_i through a_i
        directly and through every lower actor that reads a_i or a response to it (the chain rule of p23 over the
        whole hierarchy); its own level's agents do not read a_i, so their actions stay as they are.
        ``through_follower=False`` holds the lower levels' responses fixed instead (the naive gradient). Two agents:
        row 0 is the leader's ``Q1/G1(s, a1, mu2(o2, a1))`` (p23), row 1 the follower's with a1 fixed (p25). Critic
        parameters are held fixed in every row.
        """
        through = True if through_follower is None else through_follower
        critics = jax.lax.stop_gradient(critics)
        sg = jax.lax.stop_gradient
        order = agent_order(self.levels)
        own, fixed, rows = {}, {}, {}
        for pos, i in enumerate(order):
            # a_i live in theta_i, on the fixed actions of the agents before it (its actor reads those above it)
            own[i] = self.action(i, actors[i], obs[:, i], fixed, for_update=True)
            row = dict(fixed)
            if pos + 1 < len(order):
                fixed[i] = sg(own[i])
                row[i] = own[i] if through else fixed[i]
                for j in order[pos + 1:]:  # the later agents respond; a_i reaches those below its level
                    row[j] = self.action(j, sg(actors[j]), obs[:, j], row, for_update=True)
            row[i] = own[i]
            rows[i] = row
        x = jnp.stack([self.critic_input(obs, *[rows[i][j] for j in range(self.n)])[:, i] for i in range(self.n)],
                      axis=1)
        return self.critic_stack.apply_update(critics, x)

    def actor_losses(self, actors, critics, lam: jax.Array, obs: jax.Array, through_follower: bool | None = None):
        """``([K] per-agent losses mean_B(-Q_i + pen_i(G_i)), [B, 2, K] values)``; minimising loss i over
        theta_i is the ascent of p22a/p22c."""
        v = self.actor_values(actors, critics, obs, through_follower)
        per_sample = -v[..., Q]
        if self.config.constrained:
            per_sample = per_sample + self.lagrangian.penalty(lam, v[..., G])
        return jnp.mean(per_sample, axis=0), v

    def _loss(self, params, state: MADDPGState, batch: Transition, targets: jax.Array):
        critics, actors = params
        pred = self.values(critics, batch.obs, batch.action, for_update=True)
        per_net = jnp.mean((pred - jax.lax.stop_gradient(targets)) ** 2, axis=0)  # [K agents, kinds]
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
            # the authors' train() of one agent after another (leader before follower), in decision order: an
            # agent's actor loss (and multiplier) at the actions of the STEPPED actors of the agents before it, those
            # after it not yet stepped; the agents of one level too (C-MADDPG's agent 1 after agent 0). Adam is
            # elementwise, so the earlier agents' steps stand.
            order = agent_order(self.levels)
            grads_now = list(g_act)
            for pos in range(1, self.n):
                who, before = order[pos], set(order[:pos])

                def agent_loss(theta, who=who, before=before, stepped=actors):
                    mixed = tuple(stepped[a] if a in before else theta if a == who else state.actors[a]
                                  for a in range(self.n))
                    loss, v_new = self.actor_losses(mixed, state.critics, state.lam, batch.obs)
                    return loss[who], (loss, v_new)

                grads_now[who], (loss_new, v_new) = jax.grad(agent_loss, has_aux=True)(state.actors[who])
                upd, actor_opt = self.actor_opt.update(tuple(grads_now), state.actor_opt, state.actors)
                actors = optax.apply_updates(state.actors, upd)
                v = v.at[:, who].set(v_new[:, who])
                actor_loss = actor_loss.at[who].set(loss_new[who])
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
