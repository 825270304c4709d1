"""Auto-reset wrapper with episode statistics, and a batched rollout helper."""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from flax import struct

from envs_jax.env import DrivingEnv, EnvState


@struct.dataclass
class AutoResetState:
    env_state: EnvState
    episode_return: jax.Array  # [2] running sums of the current episode
    episode_cost: jax.Array  # [2]
    episode_length: jax.Array
    episode_crash: jax.Array  # any crash so far
    episode_arrived: jax.Array  # [2] arrived at any step
    episode_offroad: jax.Array  # any vehicle off the road at any step
    episode_distance: jax.Array  # [2] path length driven (sum of per-step displacements, m)


class AutoResetWrapper:
    """Resets an environment as soon as an episode ends (gymnax / JaxMARL style).

    ``step`` returns the first observation of the next episode when ``done``;
    ``info["terminal_obs"]`` keeps the last observation of the finished one (for
    bootstrapping), and ``info["returned_episode"]`` flags the step on which an
    episode ended, with its ``episode_return[2]``, ``episode_cost[2]``,
    ``episode_length``, ``episode_crash``, ``episode_arrived[2]``,
    ``episode_offroad`` (any vehicle left the road) and ``episode_distance[2]``
    (path length per vehicle: the sum of its per-decision displacements).
    """

    def __init__(self, env: DrivingEnv):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def reset(self, key, params=None):
        obs, st = self.env.reset(key, params)
        zeros = jnp.zeros(2, st.x.dtype)
        return obs, AutoResetState(st, zeros, zeros, jnp.zeros((), jnp.int32), jnp.zeros((), bool),
                                   jnp.zeros(2, bool), jnp.zeros((), bool), zeros)

    def step(self, key, state: AutoResetState, action, params=None):
        key_step, key_reset = jax.random.split(key)
        obs, st, reward, cost, done, info = self.env.step(key_step, state.env_state, action, params)
        ret = state.episode_return + reward
        cst = state.episode_cost + cost
        length = state.episode_length + 1
        crash = state.episode_crash | jnp.any(info["crashed"])
        arrived = state.episode_arrived | info["arrived"]
        offroad = state.episode_offroad | jnp.any(~info["on_road"])
        dist = state.episode_distance + jnp.hypot(st.x - state.env_state.x, st.y - state.env_state.y)
        obs_reset, st_reset = self.env.reset(key_reset, params)
        new_st = jax.tree_util.tree_map(lambda a, b: jnp.where(done, a, b), st_reset, st)
        new_obs = jnp.where(done, obs_reset, obs)
        info = dict(info)
        info.update(terminal_obs=obs, returned_episode=done, episode_return=ret, episode_cost=cst,
                    episode_length=length, episode_crash=crash, episode_arrived=arrived, episode_offroad=offroad,
                    episode_distance=dist)
        keep = lambda x: jnp.where(done, jnp.zeros_like(x), x)
        new_state = AutoResetState(new_st, keep(ret), keep(cst), keep(length), keep(crash), keep(arrived),
                                   keep(offroad), keep(dist))
        return new_obs, new_state, reward, cost, done, info


def random_actions(env: DrivingEnv) -> Callable:
    """A policy ``(key, obs) -> action`` drawing uniform random actions."""
    if env.discrete:
        return lambda key, obs: jax.random.randint(key, env.action_shape, 0, env.num_actions)
    return lambda key, obs: jax.random.uniform(key, env.action_shape, minval=-1.0, maxval=1.0)


def rollout(env: DrivingEnv, key, num_envs: int, num_steps: int, policy: Callable | None = None, params=None):
    """Run ``num_envs`` auto-resetting environments for ``num_steps`` policy steps in one program.

    ``policy(key, obs[2, 8]) -> action`` (default: uniform random). Returns a
    dict of ``[num_steps, num_envs, ...]`` arrays: reward, cost, done and the
    finished episodes' statistics (valid where ``returned_episode``). Jit it
    with ``jax.jit(rollout, static_argnums=(0, 2, 3, 4))``.
    """
    wrapped = AutoResetWrapper(env)
    params = env.default_params if params is None else params
    policy = random_actions(env) if policy is None else policy
    key, key_reset = jax.random.split(key)
    obs, state = jax.vmap(wrapped.reset, in_axes=(0, None))(jax.random.split(key_reset, num_envs), params)

    def body(carry, _):
        obs, state, key = carry
        key, key_act, key_step = jax.random.split(key, 3)
        action = jax.vmap(policy)(jax.random.split(key_act, num_envs), obs)
        obs, state, reward, cost, done, info = jax.vmap(wrapped.step, in_axes=(0, 0, 0, None))(
            jax.random.split(key_step, num_envs), state, action, params)
        out = dict(reward=reward, cost=cost, done=done, returned_episode=info["returned_episode"],
                   episode_return=info["episode_return"], episode_cost=info["episode_cost"],
                   episode_length=info["episode_length"], episode_crash=info["episode_crash"],
                   episode_arrived=info["episode_arrived"], episode_offroad=info["episode_offroad"],
                   episode_distance=info["episode_distance"])
        return (obs, state, key), out

    _, out = jax.lax.scan(body, (obs, state, key), None, length=num_steps)
    return out
