"""The part of MAPPO-L and MACPO that does not depend on the actor update (docs/algorithms.md, MAPPO-L and MACPO).

Per agent i of n: an actor ``pi_i(a | o_i)`` (a Gaussian on continuous actions, a categorical on discrete ones:
:func:`jaxsmarl.policy_head.policy_head`) and a centralised reward critic ``V_i(s)`` and cost critic ``V^c_i(s)``
on the shared observation ``s = concat(o_1, ..., o_n)`` (normalised). All agents' networks are stacked along a
leading agent axis (critics ``[n_agents, 2 (reward, cost)]``) with one Adam state per network.

One update (:meth:`PPOBase.update`) on a rollout ``traj`` (fields ``[T, E, ...]``, see
:class:`train.onpolicy.Transition`):

1. values of ``s_t`` and of ``s'_t`` (pre-reset), GAE for rewards and costs per agent (:func:`jaxsmarl.gae.gae`,
   per-agent termination vs truncation), value-target normalisers updated, advantages standardised per agent
   over the active samples (an agent is *active* at step t until its own termination in the episode; steps of a
   terminated agent that is still simulated are masked out of every loss);
2. the constraint's episode cost ``J_c``: over the episodes that ended in this rollout, the per-step cost
   averaged over agents summed over the episode (``per_agent_cost``: each agent's own), else the last value;
3. agents updated in a random order (``sequential``, HAPPO-style): each surrogate is weighted by ``factor``,
   the product of the ratios ``pi_new / pi_old`` on the buffer of every agent updated before it in this order;
   with ``sequential=False`` the factor stays 1 (a simultaneous update: the agents' updates are then
   independent);
4. the observation normaliser absorbs the rollout (after the update, so that the update sees the rollout's own
   normalisation and the ratios start at 1).

With ``absent_agents`` (an env whose episodes leave some agents without a vehicle, ``traj.present``): an absent
agent's steps are inactive, its observation enters the shared observation as zeros and its own normaliser not
at all, and ``J_c`` counts only the episodes it drove in (the agent average: over the agents present in each
episode).

The actor update of one agent is the subclass's :meth:`agent_update`.
"""

from __future__ import annotations

import abc
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import optax

from jaxsmarl.algos.ppo_config import PPOConfig
from jaxsmarl.gae import gae
from jaxsmarl.gradients import LoopCarry, gradient_update_fn
from jaxsmarl.losses import standardize, value_loss
from jaxsmarl.mlp import make_mlp
from jaxsmarl.permutation import random_permutation
from jaxsmarl.policy_head import policy_head
from jaxsmarl.running_stats import RunningStats

__all__ = ["PPOConfig", "PPOState", "Batch", "PPOBase"]

R, C = 0, 1  # kind axis of the critics: reward, cost


@flax.struct.dataclass
class PPOState:
    actor: Any  # {"net": MLP params} (+ "log_std": [k] for Gaussian policies), stacked [n_agents, ...]
    critic: Any  # MLP params stacked [n_agents, 2, ...]
    actor_opt: Any  # stacked [n_agents, ...] (MAPPO-L; unused by MACPO)
    critic_opt: Any  # stacked [n_agents, 2, ...]
    obs_stats: RunningStats  # [n_agents, obs_dim]
    value_stats: RunningStats  # [n_agents, 2]
    lagrange: jax.Array  # [n_agents] MAPPO-L multipliers
    episode_cost: jax.Array  # [n_agents] J_c of the last rollout with finished episodes


@flax.struct.dataclass
class Batch:
    """One rollout flattened to ``B = T * E`` samples, agent axis first."""

    obs: jax.Array  # [N, B, D] normalised own observations
    share: jax.Array  # [B, N * D] normalised shared observation
    action: jax.Array  # [N, B, k] (continuous) or [N, B] (discrete)
    logp: jax.Array  # [N, B] behaviour log-probabilities
    adv: jax.Array  # [N, 2, B] standardised reward / cost advantages
    target: jax.Array  # [N, 2, B] value targets (normalised)
    old_value: jax.Array  # [N, 2, B] rollout value predictions (normalised)
    active: jax.Array  # [N, B]


def _index(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


def _set(tree, i, new):
    return jax.tree.map(lambda x, y: x.at[i].set(y), tree, new)


class PPOBase(abc.ABC):
    """Shared on-policy agent: init, acting, critics, rollout preparation and the agent-sequential driver."""

    def __init__(self, config: PPOConfig):
        self.config = cfg = config
        self.head = policy_head(cfg.action_dim, cfg.num_actions, cfg.std_x_coef, cfg.std_y_coef)
        self.actor_net = make_mlp(cfg.obs_dim, cfg.hidden, cfg.layer_n, self.head.out_dim, 0.01, cfg.feature_norm)
        self.critic_net = make_mlp(cfg.share_dim, cfg.hidden, cfg.layer_n, 1, 1.0, cfg.feature_norm)
        self.carry = LoopCarry(self.actor_net.layout)  # how networks travel through the minibatch loops
        self.actor_tx = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm),
                                    optax.adam(cfg.actor_lr, eps=cfg.adam_eps))
        self.critic_tx = optax.chain(optax.clip_by_global_norm(cfg.max_grad_norm),
                                     optax.adam(cfg.critic_lr, eps=cfg.adam_eps))

    # ------------------------------------------------------------------------------------------------------
    def init(self, key) -> PPOState:
        cfg = self.config
        n = cfg.n_agents
        ka, kc = jax.random.split(key)
        dtype = jnp.zeros(()).dtype

        def actor_init(k):
            return {"net": self.actor_net.init(k), **self.head.init(dtype)}

        actor = jax.vmap(actor_init)(jax.random.split(ka, n))
        critic = jax.vmap(jax.vmap(self.critic_net.init))(jax.random.split(kc, (n, 2)))
        return PPOState(
            actor=actor, critic=critic, actor_opt=jax.vmap(self.actor_tx.init)(actor),
            critic_opt=jax.vmap(jax.vmap(self.critic_tx.init))(critic),
            obs_stats=RunningStats.create((n, cfg.obs_dim), dtype),
            value_stats=RunningStats.create((n, 2), dtype),
            lagrange=jnp.full((n,), cfg.lambda_init, dtype), episode_cost=jnp.zeros((n,), dtype))

    # ------------------------------------------------------------------------------------------------------
    @staticmethod
    def agent_batch(batch, i):
        """Agent ``i``'s slice of the update batch: obs, action, old log-prob, reward and cost advantages, value
        targets, old values and the active mask."""
        return (batch.obs[i], batch.action[i], batch.logp[i], batch.adv[i, 0], batch.adv[i, 1], batch.target[i],
                batch.old_value[i], batch.active[i])

    def normalize_obs(self, state: PPOState, obs):
        """``obs [..., N, D]`` -> normalised (identity when ``obs_norm`` is off)."""
        return state.obs_stats.normalize(obs) if self.config.obs_norm else obs

    def policy(self, actor_i, obs_n, for_update: bool = False):
        """One agent's action distribution on normalised observations (the head's ``dist``: Gaussian mean
        ``[..., k]`` and std ``[k]``, or logits ``[..., A]``).

        ``for_update=True`` (a ``[B, D]`` batch only) evaluates the same network in the form the update
        differentiates (``Network.apply_update``: reverse mode only in the column layout).
        """
        apply = self.actor_net.apply_update if for_update else self.actor_net.apply
        return self.head.dist(actor_i, apply(actor_i["net"], obs_n))

    def _all_dists(self, state, obs_n):
        """``obs_n [B, N, D]`` -> every agent's distribution, agent axis second (Gaussian std: first)."""
        return jax.vmap(self.policy, in_axes=(0, 1), out_axes=self.head.agent_axes)(state.actor, obs_n)

    def act(self, state: PPOState, obs, key):
        """Sample ``[E, N, k]`` (unbounded Gaussian; :meth:`env_action` clips to [-1, 1]) or ``[E, N]``
        (categorical) actions and their log-probs."""
        dist = self._all_dists(state, self.normalize_obs(state, obs))
        action = self.head.sample(key, dist)
        return action, self.head.log_prob(dist, action)

    def env_action(self, action):
        """What the environment receives for sampled ``action`` (Gaussian: clipped to the action box)."""
        return self.head.env_action(action)

    def greedy_act(self, state: PPOState, obs):
        """The most likely action (Gaussian: its mean clipped to the action box) for one ``[N, D]``
        observation."""
        return self.head.greedy(self._all_dists(state, self.normalize_obs(state, obs)[None]))[0]

    def values(self, critic, value_stats, share):
        """Denormalised ``[..., N, 2]`` values of every critic at ``share [..., N*D]``."""
        flat = share.reshape((-1, share.shape[-1]))
        out = self.critic_net.apply_stack(critic, flat)[..., 0]  # [N, 2, B]
        out = jnp.moveaxis(out, -1, 0).reshape(share.shape[:-1] + out.shape[:2])
        return value_stats.denormalize(out) if self.config.value_norm else out

    # ------------------------------------------------------------------------------------------------------
    def prepare(self, state: PPOState, traj):
        """GAE, normalisers, standardised advantages and ``J_c``: ``(state, Batch)`` (steps 1-2 above)."""
        cfg = self.config
        T, E, N, D = traj.obs.shape
        obs_n = self.normalize_obs(state, traj.obs)
        next_n = self.normalize_obs(state, traj.next_obs)
        if cfg.absent_agents:  # an absent agent is zeros in the shared observation, whatever it observed
            obs_n, next_n = (jnp.where(traj.present[..., None], x, 0.0) for x in (obs_n, next_n))
        share, next_share = obs_n.reshape(T, E, N * D), next_n.reshape(T, E, N * D)
        v = self.values(state.critic, state.value_stats, share)  # [T, E, N, 2]
        v_next = self.values(state.critic, state.value_stats, next_share)
        rc = jnp.stack([traj.reward, traj.cost], -1).astype(v.dtype)  # [T, E, N, 2]
        term = jnp.broadcast_to(traj.terminated[..., None], rc.shape)
        adv, ret = gae(rc, v, v_next, term, traj.done[:, :, None, None], cfg.gamma, cfg.gae_lambda)
        active = traj.active  # [T, E, N]
        mask2 = jnp.broadcast_to(active[..., None], rc.shape)
        value_stats = state.value_stats.update(ret.reshape(-1, N, 2), mask2.reshape(-1, N, 2)) \
            if cfg.value_norm else state.value_stats
        norm = (lambda x: value_stats.normalize(x, clip=jnp.inf)) if cfg.value_norm else (lambda x: x)
        target, old_value = norm(ret), norm(v)

        B = T * E
        flat = lambda x: jnp.moveaxis(x.reshape((B,) + x.shape[2:]), 1, 0)  # [T, E, N, ...] -> [N, B, ...]
        adv_f, active_f = flat(adv), flat(active)  # [N, B, 2], [N, B]
        adv_f = jax.vmap(jax.vmap(standardize, in_axes=(1, None), out_axes=0))(adv_f, active_f)  # [N, 2, B]
        batch = Batch(obs=flat(obs_n), share=share.reshape(B, N * D), action=flat(traj.action),
                      logp=flat(traj.logp), adv=adv_f, target=jnp.moveaxis(flat(target), -1, 1),
                      old_value=jnp.moveaxis(flat(old_value), -1, 1), active=active_f)

        # J_c over the episodes that ended in this rollout (the reference's aver_episode_costs).
        ended = traj.ep_returned.astype(v.dtype)  # [T, E]
        ep_cost = traj.ep_cost.astype(v.dtype)  # [T, E, N]
        if cfg.absent_agents:
            jc, counted = self._episode_cost_present(ended, ep_cost, traj.present.astype(v.dtype))
            jc = jnp.where(counted, jc, state.episode_cost)
            return state.replace(value_stats=value_stats, episode_cost=jc), batch
        n_ended = jnp.sum(ended)
        per_agent = jnp.sum(ended[..., None] * ep_cost, axis=(0, 1)) / jnp.maximum(n_ended, 1.0)
        jc = per_agent if cfg.per_agent_cost else jnp.full((N,), jnp.mean(per_agent), v.dtype)
        jc = jnp.where(n_ended > 0, jc, state.episode_cost)
        return state.replace(value_stats=value_stats, episode_cost=jc), batch

    def _episode_cost_present(self, ended, ep_cost, present):
        """``J_c [N]`` over the ended episodes counting only the agents present in each (``ended [T, E]``,
        ``ep_cost``, ``present [T, E, N]``) and whether any episode counted, per agent ``[N]``."""
        N = ep_cost.shape[-1]
        w = ended[..., None] * present  # [T, E, N]: episodes agent i drove in
        if self.config.per_agent_cost:
            n_i = jnp.sum(w, axis=(0, 1))
            return jnp.sum(w * ep_cost, axis=(0, 1)) / jnp.maximum(n_i, 1.0), n_i > 0
        n_present = jnp.sum(present, axis=-1)  # [T, E]
        mean_cost = jnp.sum(present * ep_cost, axis=-1) / jnp.maximum(n_present, 1.0)  # agent mean per episode
        counts = ended * (n_present > 0)
        n_ended = jnp.sum(counts)
        jc = jnp.sum(counts * mean_cost) / jnp.maximum(n_ended, 1.0)
        return jnp.full((N,), jc, ep_cost.dtype), jnp.full((N,), n_ended > 0)

    # ------------------------------------------------------------------------------------------------------
    def critic_step(self, critic_i, opt_i, share, target, old_value, active):
        """One clipped-Huber regression step of agent i's reward and cost critics (separate Adams, grad clips),
        ``critic_i`` / ``opt_i`` packed by :meth:`critics_for_loop`; returns ``(critic_i, opt_i, losses [2])``."""
        cfg = self.config

        def loss(p, tgt, old, share, active):
            pred = self.critic_net.apply_update(p, share)[:, 0]
            return cfg.value_loss_coef * value_loss(pred, old, tgt, active, cfg.value_clip, cfg.huber_delta)

        vals, critic_i, opt_i = self.carry.update_stack(gradient_update_fn(loss, self.critic_tx), critic_i, opt_i,
                                                        (target, old_value), (share, active))
        return critic_i, opt_i, vals

    def critics_for_loop(self, critic, opt):
        """Agent i's stacked ``[2, ...]`` critics and optimiser states in the form :meth:`critic_step` carries
        through the minibatch loop (:class:`jaxsmarl.gradients.LoopCarry`); :meth:`critics_from_loop` is the
        inverse."""
        return self.carry.pack_stack(critic, opt)

    def critics_from_loop(self, critic, opt):
        return self.carry.unpack_stack(critic, opt)

    def log_prob(self, actor_i, obs, action):
        return self.head.log_prob(self.policy(actor_i, obs), action)

    @abc.abstractmethod
    def agent_update(self, state: PPOState, i, batch: Batch, factor, key):
        """Update agent ``i``'s actor and critics; returns ``(state, info)`` (MAPPO-L, MACPO)."""

    def update(self, state: PPOState, traj, key):
        """One on-policy update on ``traj``: ``(state, info)`` (steps 1-4 of the module docstring)."""
        cfg = self.config
        state, batch = self.prepare(state, traj)
        k_order, k_agents = jax.random.split(key)
        order = (jax.random.permutation(k_order, cfg.n_agents) if cfg.sequential
                 else jnp.arange(cfg.n_agents))

        def per_agent(carry, x):
            st, factor = carry
            i, k = x
            st, info = self.agent_update(st, i, batch, factor, k)
            if cfg.sequential:
                actor_i = _index(st.actor, i)
                log_prob = lambda o, a: self.log_prob(actor_i, o, a)
                new_logp = self.actor_net.rollout(log_prob, batch.obs[i], batch.action[i])
                ratio = jnp.where(batch.active[i], jnp.exp(new_logp - batch.logp[i]), 1.0)
                factor = factor * jax.lax.stop_gradient(ratio)
            return (st, factor), (i, info)

        factor0 = jnp.ones(batch.logp.shape[1], batch.logp.dtype)
        (state, _), (idx, infos) = jax.lax.scan(per_agent, (state, factor0),
                                                 (order, jax.random.split(k_agents, cfg.n_agents)))
        # infos are in update order; put them in agent order.
        infos = jax.tree.map(lambda x: jnp.zeros_like(x).at[idx].set(x), infos)
        if cfg.obs_norm:
            mask = traj.present.reshape((-1,) + traj.present.shape[2:]) if cfg.absent_agents else None
            state = state.replace(obs_stats=state.obs_stats.update(traj.obs.reshape((-1,) + traj.obs.shape[2:]),
                                                                   mask))
        infos["episode_cost"] = state.episode_cost
        infos["order"] = order
        return state, infos

    # helpers for the subclasses
    index = staticmethod(_index)
    set_index = staticmethod(_set)

    @staticmethod
    def minibatch_indices(key, n: int, num_minibatches: int):
        """A random partition of ``range(n)`` into ``[num_minibatches, n // num_minibatches]``
        (:func:`jaxsmarl.permutation.random_permutation`)."""
        return random_permutation(key, n).reshape(num_minibatches, n // num_minibatches)
