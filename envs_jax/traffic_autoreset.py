"""Auto-reset wrapper with per-agent episode statistics for a traffic task with K controlled agents.

The K-agent counterpart of :class:`envs_jax.wrappers.AutoResetWrapper` for a
:class:`envs_jax.traffic_env.TrafficEnv` (``envs_jax.make("highway-v0", controlled_vehicles=K)``): the same
``info`` keys, each per-agent statistic ``[K]`` instead of ``[2]``, and each agent's observation flattened to
one row, ``obs [K, vehicles_count * F]``, the shape the joint-action critics take (``jaxsmarl/networks.py``).

``info["terminal_obs"]`` keeps the last observation of a finished episode (for bootstrapping);
``info["returned_episode"]`` flags the step on which an episode ended, with ``episode_return[K]``,
``episode_cost[K]``, ``episode_length``, ``episode_crash`` (any agent crashed), ``episode_arrived[K]`` (the
task's ``info["arrived"]`` on the episode's last step where it reports one, else False), ``episode_offroad`` (any
agent left the road) and ``episode_distance[K]`` (each agent's path length, the sum of its per-decision
displacements), and for the average speed ``episode_speed_sum[K]`` (each agent's speed after every step it drove:
present at the step's start and not terminated at an earlier step) with ``episode_active_steps[K]`` (the number of
those steps).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax.sparse import reset_where

__all__ = ["TrafficAutoResetState", "TrafficAutoResetWrapper"]


@struct.dataclass
class TrafficAutoResetState:
    env_state: object
    episode_return: jax.Array  # [K] running sums of the current episode
    episode_cost: jax.Array  # [K]
    episode_length: jax.Array
    episode_crash: jax.Array  # any agent crashed so far
    episode_offroad: jax.Array  # any agent off the road at any step
    episode_distance: jax.Array  # [K] path length driven (m)
    episode_speed_sum: jax.Array  # [K] speeds after the steps the agent drove
    episode_active_steps: jax.Array  # [K] steps the agent drove (present, not yet terminated)
    episode_terminated: jax.Array  # [K] terminated at some step of this episode


class TrafficAutoResetWrapper:
    """Resets a K-agent traffic environment as soon as its episode ends; flat per-agent observations."""

    def __init__(self, env):
        self.env = env
        self.obs_shape = (env.num_agents, int(np.prod(env.obs_shape[1:])))

    def __getattr__(self, name):
        return getattr(self.env, name)

    def _flat(self, obs):
        per_agent = len(self.env.obs_shape) - 1  # [n, F] Kinematics or [C, H, W] occupancy grids
        return jnp.reshape(obs, obs.shape[:obs.ndim - per_agent] + (-1,))

    def reset(self, key, params=None):
        obs, st = self.env.reset(key, params)
        zeros = jnp.zeros(self.env.num_agents, st.x.dtype)
        return self._flat(obs), TrafficAutoResetState(st, zeros, zeros, jnp.zeros((), jnp.int32),
                                                      jnp.zeros((), bool), jnp.zeros((), bool), zeros, zeros,
                                                      jnp.zeros(self.env.num_agents, jnp.int32),
                                                      jnp.zeros(self.env.num_agents, bool))

    def step(self, key, state: TrafficAutoResetState, action, params=None):
        key_step, key_reset = jax.random.split(key)
        obs, st, reward, cost, done, info = self.env.step(key_step, state.env_state, action, params)
        obs = self._flat(obs)
        idx = np.asarray(self.env.controlled)
        ret = state.episode_return + reward
        cst = state.episode_cost + cost
        length = state.episode_length + 1
        crash = state.episode_crash | jnp.any(info["crashed"])
        offroad = state.episode_offroad | jnp.any(~info["on_road"])
        prev = state.env_state
        dist = state.episode_distance + jnp.hypot(st.x[idx] - prev.x[idx], st.y[idx] - prev.y[idx])
        drove = prev.alive[idx] & ~state.episode_terminated
        speed_sum = state.episode_speed_sum + jnp.where(drove, st.speed[idx], 0.0)
        active = state.episode_active_steps + drove.astype(jnp.int32)
        terminated = state.episode_terminated | info["terminated"]
        # only the finished episodes reset (under vmap: those of the batch); intersection's warm-up costs 3 steps
        obs_reset, st_reset = reset_where(self.reset, done, key_reset, params)
        new_st = jax.tree_util.tree_map(lambda a, b: jnp.where(done, a, b), st_reset.env_state, st)
        new_obs = jnp.where(done, obs_reset, obs)
        info = dict(info)
        info.update(terminal_obs=obs, returned_episode=done, episode_return=ret, episode_cost=cst,
                    episode_length=length, episode_crash=crash,
                    episode_arrived=info.get("arrived", jnp.zeros(self.env.num_agents, bool)),
                    episode_offroad=offroad, episode_distance=dist, episode_speed_sum=speed_sum,
                    episode_active_steps=active)
        keep = lambda x: jnp.where(done, jnp.zeros_like(x), x)
        new_state = TrafficAutoResetState(new_st, keep(ret), keep(cst), keep(length), keep(crash), keep(offroad),
                                          keep(dist), keep(speed_sum), keep(active), keep(terminated))
        return new_obs, new_state, reward, cost, done, info
