"""The off-policy training loop (:func:`make_offpolicy_train`, CSQ and the MADDPG family).

One iteration = act in every env, step the auto-resetting envs, store the transitions (with the pre-reset observation
as ``s'`` and per-agent
``terminated``), then ``updates_per_step`` gradient updates once ``warmup`` transitions are stored (Algorithm 1's
inner loop); warm-up gating is a real branch, not a select, since the iteration index is unbatched. Its agent
provides ``init(key)``, ``exploration(env_step)`` (a pytree: CSQ's per-agent epsilon, MADDPG's noise scales),
``act(state, obs, key, explore)``, ``greedy_act(state, obs)``, ``update(state, batch, key, explore) -> (state,
info)``, ``transition_example()`` and ``Transition``; the config provides ``warmup``, ``batch_size``,
``updates_per_step`` and ``buffer_size``.

It builds a :class:`train.trainer.Trainer` (the contract every loop fulfils).
"""

from __future__ import annotations

from typing import Any

import flax.struct
import jax
import jax.numpy as jnp

from jaxsmarl import buffers, metrics
from train.trainer import Trainer, assemble_trainer

__all__ = ["RunnerState", "make_offpolicy_train"]


@flax.struct.dataclass
class RunnerState:
    agent: Any
    buffer: buffers.BufferState
    env_state: Any  # [num_envs, ...]
    obs: jax.Array  # [num_envs, n_agents, obs_dim]
    key: jax.Array
    iteration: jax.Array  # int32 loop iterations done


def make_offpolicy_train(config: dict, env, agent) -> Trainer:
    """The replay-based loop for ``agent``. ``env``: ``(env, wrapped_env, params)``."""
    env, wrapped, params = env
    E = config["num_envs"]
    U = config["updates_per_step"]
    B = config["batch_size"]
    warmup = config["warmup"]
    capacity = min(config["buffer_size"], config["total_steps"])  # a never-filled buffer needs no more slots

    def init(key) -> RunnerState:
        k_agent, k_env, k_run = jax.random.split(key, 3)
        obs, env_state = jax.vmap(wrapped.reset, in_axes=(0, None))(jax.random.split(k_env, E), params)
        return RunnerState(agent=agent.init(k_agent), buffer=buffers.init(agent.transition_example(), capacity),
                           env_state=env_state, obs=obs, key=k_run, iteration=jnp.int32(0))

    # A zero update-info record, for iterations before the warm-up ends.
    def _update_info_zeros():
        st = jax.eval_shape(agent.init, jax.random.PRNGKey(0))
        batch = jax.eval_shape(lambda: jax.tree.map(lambda x: jnp.zeros((B,) + x.shape, x.dtype),
                                                    agent.transition_example()))
        explore = jax.eval_shape(agent.exploration, jnp.int32(0))
        info = jax.eval_shape(agent.update, st, batch, jax.random.PRNGKey(0), explore)[1]
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), info)

    def iteration(rs: RunnerState, t):
        key, k_act, k_env, k_upd = jax.random.split(rs.key, 4)
        eps = agent.exploration(t * E)
        actions = agent.act(rs.agent, rs.obs, k_act, eps)
        obs, env_state, reward, cost, done, info = jax.vmap(wrapped.step, in_axes=(0, 0, 0, None))(
            jax.random.split(k_env, E), rs.env_state, actions, params)
        next_obs = jnp.where(done[:, None, None], info["terminal_obs"], obs)
        extra = {"active": info["alive"]} if "active" in agent.Transition.__dataclass_fields__ else {}
        tr = agent.Transition(obs=rs.obs, action=actions, reward=reward, cost=cost, next_obs=next_obs,
                              terminated=info["terminated"], truncated=info["truncated"], **extra)
        buf = buffers.add(rs.buffer, tr)

        def learn(agent_state):
            def one(a_state, k):
                k_sample, k_update = jax.random.split(k)
                return agent.update(a_state, buffers.sample(buf, k_sample, B), k_update, eps)

            agent_state, infos = jax.lax.scan(one, agent_state, jax.random.split(k_upd, U))
            return agent_state, jax.tree.map(lambda x: jnp.mean(x, axis=0), infos)

        def skip(agent_state):
            return agent_state, _update_info_zeros()

        agent_state, upd = jax.lax.cond((t + 1) * E >= warmup, learn, skip, rs.agent)
        out = {"episode": metrics.episode_record(info), "explore": eps, "update": upd,
               "updated": (t + 1) * E >= warmup}
        return RunnerState(agent=agent_state, buffer=buf, env_state=env_state, obs=obs, key=key,
                           iteration=rs.iteration + 1), out

    def make_chunk(length: int):
        def run(rs: RunnerState, start_iter):
            ts = jnp.asarray(start_iter, jnp.int32) + jnp.arange(length, dtype=jnp.int32)
            return jax.lax.scan(iteration, rs, ts)

        return run

    return assemble_trainer(config, env, wrapped, params, agent, init, make_chunk)
