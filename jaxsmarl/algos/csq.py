"""Constrained Stackelberg Q-learning (CSQ, paper Algorithm 1, eqs. p10-p14) as pure JAX functions.

Per agent i: a centralized reward critic ``Q_i(s, a1, a2)`` and cost critic ``G_i(s, a1, a2)``
(:mod:`jaxsmarl.networks`, stacked as ``[n_agents, 2]`` = {Q, G}), target copies, one Adam over the stack (Adam is
elementwise, so this equals one optimizer per critic as the authors had).

* Acting (Alg. 1, "sample actions with epsilon-greedy according to (p14)"): level by level, agent i explores
  with probability ``eps_i``, otherwise plays its part of the constrained Stackelberg equilibrium of the
  sub-game that starts at its level, given the actions already executed above it. For two agents: the leader
  plays a1* of (p14); the follower plays its constrained best response BR(a1) to the EXECUTED leader action
  (which may be random), as in the authors' code.
* Targets (Alg. 1): ``y_i = r_i + gamma (1 - t_i) Q_i^targ(s', a'),  g_i = c_i + gamma (1 - t_i) G_i^targ(s', a')``
  with ``a'`` the equilibrium (p14) of the online critics at s' (p12/p13). ``t_i`` is agent i's OWN terminal
  flag, so an agent that is done stops bootstrapping while the episode goes on for the other.
* Loss: ``sum_i mean_B (Q_i(s, a) - y_i)^2 + (G_i(s, a) - g_i)^2``; soft target update
  ``theta' <- (1 - tau) theta' + tau theta`` every ``target_update_every`` updates (authors: tau 0.01 / 10).

Hierarchies (``hierarchy``, :mod:`jaxsmarl.hierarchy`; the paper's multi-agent expansion): K agents with critics
over the joint-action grid ``A^K``; the equilibrium of any hierarchy (levels solved by backward induction, the agents
on one level at the pure equilibrium of :func:`jaxsmarl.stackelberg.stackelberg_equilibrium`). Acting goes level by
level: each agent of a level explores with probability ``eps_i``, otherwise plays its part of the equilibrium of the
sub-game of its own and the later levels, given the actions executed on the levels above it. ``None`` is the chain
``0 | 1 | ... | K-1``: for two agents the leader-follower game above.

Options reproducing the authors' code (docs/algorithms.md, CSQ): ``leader_rule="authors"``, ``infeasible="argmax"``,
``td_action_state="current"`` + ``td_action_noise=True`` (their target actions come from s with exploration),
``bootstrap_on_truncation=False`` (their t_i includes the time limit), ``terminal_mask="batch_mean"`` (their
targets bootstrap every transition with the discount scaled by the batch's done fraction, :mod:`jaxsmarl.bootstrap`).
"""

from __future__ import annotations

import math
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxsmarl import bootstrap, networks
from jaxsmarl.algos.csq_config import CSQConfig
from jaxsmarl.exploration import linear_decay
from jaxsmarl.hierarchy import agent_order
from jaxsmarl.stackelberg import stackelberg_equilibrium
from jaxsmarl.transition import MaskedTransition, Transition

__all__ = ["CSQAgent", "CSQConfig", "CSQState", "MaskedTransition", "Transition"]

Q, G = 0, 1  # kind axis of the stacked critics


@flax.struct.dataclass
class CSQState:
    params: Any  # stacked critics [n_agents, 2 (Q, G), ...]
    target_params: Any
    opt_state: Any
    n_updates: jax.Array  # int32, gradient steps taken


class CSQAgent:
    """CSQ as a bundle of pure functions over :class:`CSQState` (jit/vmap them freely)."""

    Transition = Transition

    def __init__(self, config: CSQConfig):
        self.config = config
        self.module = networks.JointActionMLP(hidden=tuple(config.hidden_sizes), init_scheme=config.init)
        self.optimizer = optax.adam(config.lr)
        self.Transition = MaskedTransition if config.absent_agents else Transition

    # ---------------------------------------------------------------------------------------------
    def init(self, key: jax.Array) -> CSQState:
        """Online critics, identical target copies (Alg. 1 initialisation), Adam state."""
        c = self.config
        params = networks.init_stacked(self.module, key, c.obs_dim, c.num_actions, shape=(c.n_agents, 2))
        return CSQState(params=params, target_params=params, opt_state=self.optimizer.init(params),
                        n_updates=jnp.int32(0))

    def epsilon(self, env_step: jax.Array) -> jax.Array:
        """Per-agent exploration probability after ``env_step`` steps: ``max(min, start - decay * step)``."""
        c = self.config
        return linear_decay(c.eps_start, c.eps_min, c.eps_decay, env_step)

    def exploration(self, env_step: jax.Array) -> jax.Array:
        """The training loop's exploration parameters: the per-agent epsilon."""
        return self.epsilon(env_step)

    def transition_example(self) -> Transition:
        c = self.config
        n = c.n_agents
        fields = {"obs": jnp.zeros((n, c.obs_dim)), "action": jnp.zeros((n,), jnp.int32), "reward": jnp.zeros((n,)),
                  "cost": jnp.zeros((n,)), "next_obs": jnp.zeros((n, c.obs_dim)),
                  "terminated": jnp.zeros((n,), bool), "truncated": jnp.zeros((), bool)}
        if c.absent_agents:
            fields["active"] = jnp.ones((n,), bool)
        return self.Transition(**fields)

    # ---------------------------------------------------------------------------------------------
    def values(self, params, obs: jax.Array) -> jax.Array:
        """All critics over all joint actions: obs ``[..., n, D]`` -> ``[..., n, 2, A1, ..., An]``."""
        return networks.joint_values(params, obs, self.config.num_actions)

    def _solve(self, values: jax.Array, level: int = 0) -> jax.Array:
        """The equilibrium of the sub-game of levels ``level..`` of the hierarchy.

        ``values`` ``[..., n, 2, A_j...]`` over the action axes of the agents ``j`` of levels ``level..`` in index
        order (the actions of the levels above already fixed) -> int32 ``[..., m]``, the same agents' actions in
        index order."""
        c = self.config
        levels = c.levels[level:]
        agents = sorted(agent_order(levels))  # the remaining agents, in index (= axis) order
        ax = values.ndim - 2 - len(agents)  # the agent axis
        pick = lambda i, kind: values[(slice(None),) * ax + (i, kind)]
        position = {a: j for j, a in enumerate(agents)}
        sub = None if c.hierarchy is None else tuple(tuple(position[a] for a in lv) for lv in levels)
        return stackelberg_equilibrium(
            [pick(i, Q) for i in agents],
            [pick(i, G) for i in agents],
            [c.cost_threshold[i] for i in agents],
            infeasible=c.infeasible, leader_rule=c.leader_rule, tie_break=c.resolved_tie_break, hierarchy=sub,
        )

    def equilibrium(self, values: jax.Array) -> jax.Array:
        """Greedy joint action from ``values`` ``[..., n, 2, A1..An]`` -> int32 ``[..., n]`` (p14 for two agents;
        the hierarchy's equilibrium for K)."""
        return self._solve(values, 0)

    def solve_equilibrium(self, params, obs: jax.Array) -> jax.Array:
        """p14 at ``obs`` ``[..., 2, D]`` evaluating only what backward induction needs (two-level Stackelberg rule):
        the follower's Q2/G2 on all A1*A2 pairs, then the leader's Q1/G1 only at the A1 pairs (a1, BR(a1)). This is
        40% fewer critic rows than :meth:`equilibrium` of :meth:`values` and gives the same actions (up to
        float rounding of exact ties). Other hierarchies of several levels use :meth:`_solve_levels`; the authors'
        rule and a single level (no hierarchy: every agent needs the whole grid) use the full grid."""
        c = self.config
        if c.leader_rule != "stackelberg" or len(c.levels) == 1:
            return self.equilibrium(self.values(params, obs))
        if c.n_agents != 2 or c.levels != ((0,), (1,)):
            return self._solve_levels(params, obs)
        rule = dict(infeasible=c.infeasible, leader_rule="stackelberg", tie_break=c.resolved_tie_break)
        a1_n = c.num_actions[0]
        follower = jax.tree.map(lambda x: x[1:], params)
        vf = networks.joint_values(follower, obs[..., 1:, :], c.num_actions)[..., 0, :, :, :]  # [..., 2, A1, A2]
        br = stackelberg_equilibrium([vf[..., Q, :, :]], [vf[..., G, :, :]], [c.cost_threshold[1]], **rule)[..., 0]
        a1_grid = jnp.broadcast_to(jnp.arange(a1_n, dtype=jnp.int32), br.shape)
        pairs = jnp.stack([a1_grid, br], axis=-1)  # [..., A1, 2]: (a1, BR(a1))
        leader = jax.tree.map(lambda x: x[:1], params)
        lead_obs = jnp.broadcast_to(obs[..., None, :1, :], br.shape + (1, obs.shape[-1]))
        vl = networks.values_at(leader, lead_obs, pairs, c.num_actions)[..., 0, :]  # [..., A1, 2]
        a1 = stackelberg_equilibrium([vl[..., Q]], [vl[..., G]], [c.cost_threshold[0]], **rule)[..., 0]
        a2 = jnp.take_along_axis(br, a1[..., None], axis=-1)[..., 0]
        return jnp.stack([a1, a2], axis=-1)

    def _solve_levels(self, params, obs: jax.Array) -> jax.Array:
        """The hierarchy's equilibrium at ``obs`` ``[..., n, D]`` evaluating only what backward induction needs:
        the last level's critics on the whole grid, then each agent of an earlier level only at the joint actions
        of its prefix (the levels above it), its own level and the later levels' replies. A chain of 4 agents
        needs 1560 critic rows per state instead of 5000, two leaders over two followers 2600; the actions are
        the full grid's (up to float rounding of exact ties)."""
        c = self.config
        k = c.n_agents
        order = agent_order(c.levels)
        to_agent = np.asarray([order.index(a) for a in range(k)])  # decision position of each agent
        sizes = [c.num_actions[a] for a in order]
        rule = dict(infeasible=c.infeasible, leader_rule="stackelberg", tie_break=c.resolved_tie_break)
        batch, d = obs.shape[:-2], obs.shape[-1]
        nb = len(batch)

        def take(level):  # the critics of a level's agents (a slice for one agent: the chain's ops as before)
            idx = slice(level[0], level[0] + 1) if len(level) == 1 else np.asarray(level)
            return jax.tree.map(lambda x: x[idx], params), obs[..., idx, :]

        def solve(vals, level):  # vals [..., P, A_level..., s, 2] -> the level's joint action [..., P, s]
            s = len(level)
            one = None if s == 1 else (tuple(range(s)),)  # one level: the agents play an equilibrium
            return stackelberg_equilibrium([vals[..., i, Q] for i in range(s)], [vals[..., i, G] for i in range(s)],
                                           [c.cost_threshold[a] for a in level], hierarchy=one, **rule)

        last = c.levels[-1]
        p = k - len(last)  # decision position of the last level's first agent
        net, o = take(last)
        v = networks.joint_values(net, o, c.num_actions)  # [..., s, 2, A (agent order)]
        v = jnp.transpose(v, tuple(range(nb + 2)) + tuple(nb + 2 + a for a in order))  # actions in decision order
        v = jnp.reshape(v, batch + (len(last), 2, math.prod(sizes[:p])) + tuple(sizes[p:]))
        v = jnp.moveaxis(jnp.moveaxis(v, nb, -1), nb, -1)  # [..., P, A_last..., s, 2]
        cont = solve(v, last)  # [..., prod(sizes[:j]), k - j]: positions j.. for every prefix of positions < j
        end = p
        for level in reversed(c.levels[:-1]):
            j = end - len(level)  # decision position of this level's first agent
            m, n_level = math.prod(sizes[:end]), math.prod(sizes[j:end])
            digits = np.stack(np.unravel_index(np.arange(m), sizes[:end]), -1).astype(np.int32)  # [m, end]
            joint = jnp.concatenate([jnp.broadcast_to(digits, batch + digits.shape), cont], axis=-1)  # decision order
            joint = joint[..., to_agent]  # agent order
            net, o = take(level)
            o = jnp.broadcast_to(o[..., None, :, :], batch + (m, len(level), d))
            vals = networks.values_at(net, o, joint, c.num_actions)  # [..., m, s, 2]
            vals = jnp.reshape(vals, batch + (m // n_level,) + tuple(sizes[j:end]) + vals.shape[-2:])
            r = solve(vals, level)  # [..., m // n_level, s]
            flat = jnp.ravel_multi_index(tuple(r[..., i] for i in range(len(level))), sizes[j:end], mode="clip")
            chosen = jnp.arange(m // n_level, dtype=jnp.int32) * n_level + flat  # flat prefix incl. this level
            rest = jnp.take_along_axis(cont, chosen[..., None], axis=-2)
            cont = jnp.concatenate([r, rest], axis=-1)
            end = j
        return cont[..., 0, :][..., to_agent]

    def policy(self, values: jax.Array, key: jax.Array, eps: jax.Array) -> jax.Array:
        """Epsilon-greedy hierarchical acting: level by level, each agent explores with prob. ``eps[i]``, else
        plays its part of the equilibrium of the sub-game of its and the later levels, given the actions executed
        on the levels above. ``eps = 0`` gives :meth:`equilibrium`."""
        c = self.config
        n = c.n_agents
        batch = values.shape[: values.ndim - 2 - n]
        keys = jax.random.split(key, 2 * n)
        sub = values  # [..., n, 2, A_j...]: the axes of the agents not yet executed, in index order
        remaining = list(range(n))
        actions = [None] * n
        for li, level in enumerate(c.levels):
            greedy = self._solve(sub, li)  # [..., len(remaining)], remaining agents in index order
            for i in level:
                explore = jax.random.uniform(keys[2 * i], batch) < eps[i]
                rand = jax.random.randint(keys[2 * i + 1], batch, 0, c.num_actions[i])
                actions[i] = jnp.where(explore, rand, greedy[..., remaining.index(i)]).astype(jnp.int32)
            if li + 1 < len(c.levels):  # fix this level's executed actions in every agent's tensors
                for i in sorted(level, reverse=True):
                    axis = len(batch) + 2 + remaining.index(i)
                    shape = sub.shape[:axis] + (1,) + sub.shape[axis + 1 :]
                    idx = jnp.broadcast_to(actions[i].reshape(batch + (1,) * (sub.ndim - len(batch))), shape)
                    sub = jnp.take_along_axis(sub, idx, axis=axis).squeeze(axis)
                    remaining.remove(i)
        return jnp.stack(actions, axis=-1)

    def act(self, state: CSQState, obs: jax.Array, key: jax.Array, eps: jax.Array) -> jax.Array:
        """Actions ``[..., n]`` for observations ``[..., n, D]`` (online critics)."""
        return self.policy(self.values(state.params, obs), key, eps)

    def greedy_act(self, state: CSQState, obs: jax.Array) -> jax.Array:
        return self.equilibrium(self.values(state.params, obs))

    # ---------------------------------------------------------------------------------------------
    def td_targets(self, state: CSQState, batch: Transition, key: jax.Array, eps: jax.Array) -> jax.Array:
        """``[B, n, 2]`` targets ``(r_i, c_i) + gamma (1 - t_i) (Q_i^targ, G_i^targ)(s', a')`` (Alg. 1)."""
        c = self.config
        eq_obs = batch.next_obs if c.td_action_state == "next" else batch.obs
        eq_params = state.params if c.td_equilibrium_net == "online" else state.target_params
        if c.td_action_noise:
            a_next = self.policy(self.values(eq_params, eq_obs), key, eps)
        else:
            a_next = self.solve_equilibrium(eq_params, eq_obs)
        boot = networks.values_at(state.target_params, batch.next_obs, a_next, c.num_actions)
        keep = bootstrap.continuation(batch.terminated, batch.truncated, c.terminal_mask, c.bootstrap_on_truncation)
        rc = jnp.stack([batch.reward, batch.cost], axis=-1)  # [B, n, 2]
        return rc + c.gamma * keep[..., None] * boot

    def loss(self, params, batch: Transition, targets: jax.Array):
        pred = networks.values_at(params, batch.obs, batch.action, self.config.num_actions)
        if self.config.absent_agents:  # means over each agent's own present transitions
            w = batch.active.astype(pred.dtype)[..., None]  # [B, n, 1]
            count = jnp.maximum(jnp.sum(w, axis=0), 1.0)
            per_net = jnp.sum(w * (pred - jax.lax.stop_gradient(targets)) ** 2, axis=0) / count
            return jnp.sum(per_net), (per_net, jnp.sum(w * pred, axis=0) / count)
        per_net = jnp.mean((pred - jax.lax.stop_gradient(targets)) ** 2, axis=0)  # [n, 2]
        return jnp.sum(per_net), (per_net, jnp.mean(pred, axis=0))

    def update(self, state: CSQState, batch: Transition, key: jax.Array, eps: jax.Array):
        """One gradient step on all critics + the authors' periodic soft target update. Returns (state, info)."""
        c = self.config
        targets = self.td_targets(state, batch, key, eps)
        grads, (per_net, mean_pred) = jax.grad(self.loss, has_aux=True)(state.params, batch, targets)
        updates, opt_state = self.optimizer.update(grads, state.opt_state, state.params)
        params = optax.apply_updates(state.params, updates)
        n = state.n_updates  # the authors soft-update when train_step > 0 and train_step % update_rate == 0
        do_soft = (n > 0) & (n % c.target_update_every == 0)
        soft = networks.soft_update(state.target_params, params, c.tau)
        target_params = jax.tree.map(lambda s, t: jnp.where(do_soft, s, t), soft, state.target_params)
        info = {"loss_q": per_net[:, Q], "loss_g": per_net[:, G], "q_mean": mean_pred[:, Q], "g_mean": mean_pred[:, G]}
        return CSQState(params=params, target_params=target_params, opt_state=opt_state, n_updates=n + 1), info
