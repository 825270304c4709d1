"""The compiled on-policy loop (MAPPO-L, MACPO): rollout of ``num_envs`` auto-resetting envs with
``lax.scan``, then one update, in one program per chunk.

One *cycle* = ``rollout_length`` loop iterations (each steps every env once) + one ``agent.update``; a chunk is
a whole number of cycles (``chunk_steps`` and ``total_steps`` are multiples of ``num_envs * rollout_length``,
checked by the config), so a chunk's ``metrics["episode"]`` (``[n_cycles, T, E]``) is reshaped to
``[chunk_iters, E]`` as the :mod:`train.trainer` contract asks. ``metrics["update"]`` holds the agent's update
diagnostics per cycle.

Bookkeeping per env: ``alive[E, N]``: agent i has not terminated yet in the current episode (per-agent
termination: a terminated agent is still simulated until the episode ends, but its later steps are inactive).
The transition keeps the pre-reset next observation (``info["terminal_obs"]`` at the end of an episode), the
agent's own ``terminated`` and the episode's ``done``, so GAE bootstraps through a time limit but not through a
termination (:mod:`jaxsmarl.gae`). In an env with absent agents (``has_absent_agents``, ``info["alive"]``) a
step is active only for the agents present in its episode, and ``present`` travels with the transition.
"""

from __future__ import annotations

from typing import Any

import flax.struct
import jax
import jax.numpy as jnp

from jaxsmarl import metrics
from train.trainer import Trainer, assemble_trainer

__all__ = ["Transition", "OnPolicyState", "make_onpolicy_train"]


@flax.struct.dataclass
class Transition:
    obs: jax.Array  # [..., N, D]
    action: jax.Array  # [..., N, k] raw Gaussian sample, or [..., N] discrete action
    logp: jax.Array  # [..., N]
    reward: jax.Array  # [..., N]
    cost: jax.Array  # [..., N]
    next_obs: jax.Array  # [..., N, D] before auto-reset
    terminated: jax.Array  # [..., N] the agent's own termination at this step
    done: jax.Array  # [...] the episode ended at this step
    active: jax.Array  # [..., N] the agent had not terminated before this step
    ep_returned: jax.Array  # [...] an episode ended (its statistics below are valid)
    ep_cost: jax.Array  # [..., N] that episode's cost per agent
    present: Any = None  # [..., N] the agent drives in this step's episode (envs with absent agents only)


@flax.struct.dataclass
class OnPolicyState:
    agent: Any
    env_state: Any  # [E, ...]
    obs: jax.Array  # [E, N, D]
    alive: jax.Array  # [E, N]
    key: jax.Array
    iteration: jax.Array  # int32 loop iterations done


def make_onpolicy_train(config: dict, env, agent) -> Trainer:
    """The on-policy trainer of ``agent`` (a :class:`jaxsmarl.algos.ppo_base.PPOBase`). ``env``:
    ``(env, wrapped_env, params)``."""
    env, wrapped, params = env
    E, T = config["num_envs"], config["rollout_length"]
    cycle = E * T
    if config["total_steps"] % cycle or config["chunk_steps"] % cycle:
        raise ValueError(f"total_steps and chunk_steps must be multiples of num_envs * rollout_length ({cycle})")
    n_agents = env.num_agents
    absent = bool(getattr(env, "has_absent_agents", False))

    def init(key) -> OnPolicyState:
        k_agent, k_env, k_run = jax.random.split(key, 3)
        obs, env_state = jax.vmap(wrapped.reset, in_axes=(0, None))(jax.random.split(k_env, E), params)
        return OnPolicyState(agent=agent.init(k_agent), env_state=env_state, obs=obs,
                             alive=jnp.ones((E, n_agents), bool), key=k_run, iteration=jnp.int32(0))

    def env_step(rs: OnPolicyState, _):
        key, k_act, k_env = jax.random.split(rs.key, 3)
        action, logp = agent.act(rs.agent, rs.obs, k_act)
        obs, env_state, reward, cost, done, info = jax.vmap(wrapped.step, in_axes=(0, 0, 0, None))(
            jax.random.split(k_env, E), rs.env_state, agent.env_action(action), params)
        term = info["terminated"]
        next_obs = jnp.where(done[:, None, None], info["terminal_obs"], obs)
        present = info["alive"] if absent else None  # presence is drawn per episode: this step's episode
        tr = Transition(obs=rs.obs, action=action, logp=logp, reward=reward, cost=cost, next_obs=next_obs,
                        terminated=term, done=done, active=rs.alive if present is None else rs.alive & present,
                        ep_returned=info["returned_episode"], ep_cost=info["episode_cost"], present=present)
        alive = jnp.where(done[:, None], True, rs.alive & ~term)
        rs = rs.replace(env_state=env_state, obs=obs, alive=alive, key=key, iteration=rs.iteration + 1)
        return rs, (tr, metrics.episode_record(info))

    def one_cycle(rs: OnPolicyState, _):
        rs, (traj, records) = jax.lax.scan(env_step, rs, None, length=T)
        key, k_upd = jax.random.split(rs.key)
        agent_state, info = agent.update(rs.agent, traj, k_upd)
        return rs.replace(agent=agent_state, key=key), (records, info)

    def make_chunk(length: int):
        def run(rs: OnPolicyState, start_iter):
            del start_iter  # the on-policy update does not depend on the step count
            rs, (records, info) = jax.lax.scan(one_cycle, rs, None, length=length // T)
            records = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), records)
            return rs, {"episode": records, "update": info}

        return run

    return assemble_trainer(config, env, wrapped, params, agent, init, make_chunk)
