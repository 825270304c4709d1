"""Traffic environment whose K controlled vehicles take continuous actions (highway-env ``ContinuousAction``).

Same API and frame loop as :class:`envs_jax.traffic_env.TrafficEnv`; the controlled
slots are plain ``Vehicle`` s (highway-env's ``ContinuousAction.vehicle_class``):
on the first frame of a step each one's action in ``[-1, 1]^d`` is mapped to an
acceleration and/or a steering angle (:func:`envs_jax.vehicle.continuous_action`,
with the ranges of the params), stored, and held for every frame of the step;
``road.act`` leaves them alone, and a crashed vehicle's stored command becomes
``steering 0, acceleration -speed`` as ``Vehicle.clip_actions`` mutates it. The other
slots are IDM/MOBIL drivers. ``action`` has shape ``[K, d]`` with ``d`` = 1
(``longitudinal`` or ``lateral`` only) or 2 (``[acceleration, steering]``).

Observations are the task's ``obs_config``: a Kinematics config
(:mod:`envs_jax.kinematic_obs`) or an occupancy grid (:mod:`envs_jax.occupancy_grid`).
A task with a ``max_steps`` attribute truncates after that many steps (highway-env's
float clock, computed on the host) instead of ``ceil(duration * policy_frequency)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import occupancy_grid
from envs_jax import vehicle as Veh
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams


class ContinuousTrafficEnv(TrafficEnv):
    """A traffic task with continuous-action agents. Create with :func:`envs_jax.make`."""

    discrete = False

    def __init__(self, task: Task, default_params: TrafficParams):
        self.longitudinal = bool(task.longitudinal)
        self.lateral = bool(task.lateral)
        self.action_size = int(self.longitudinal) + int(self.lateral)
        super().__init__(task, default_params)
        # controlled slots are plain vehicles: neither MDP nor IDM drivers
        self.is_mdp = np.zeros(self.num_slots, bool)
        self.is_idm = np.ones(self.num_slots, bool)
        self.is_idm[list(self.controlled)] = False
        self.num_actions = None
        self.action_shape = (self.num_agents, self.action_size)
        self.obs_shape = (self.num_agents,) + tuple(task.obs_config.shape)

    def __repr__(self):
        return (f"ContinuousTrafficEnv({self.name!r}, slots={self.num_slots}, controlled={self.controlled}, "
                f"frames={self.frames}, action={self.action_shape}, obs={self.obs_shape})")

    def observe(self, state, params, key=None):
        if isinstance(self.obs_config, occupancy_grid.OccupancyGridConfig):
            return occupancy_grid.observe(self.obs_config, self.road, state, self.controlled)
        return super().observe(state, params, key)

    def _decide(self, st, action, params):
        """``ContinuousAction.act`` of every agent: store its acceleration and steering."""
        return store_continuous_actions(self, st, action, params)

    def _step(self, key, state, action, params, record):
        obs, state, reward, cost, done, info, trajectory = super()._step(key, state, action, params, record)
        if hasattr(self.task, "max_steps"):
            truncated = state.time >= self.task.max_steps
            done = jnp.all(info["terminated"]) | truncated
            info = dict(info, truncated=truncated)
        return obs, state, reward, cost, done, info, trajectory

    def check_action(self, action):
        """Floats of shape ``[K, d]`` in ``[-1, 1]`` (``ValueError`` in eager use on a wrong shape or a
        non-finite value; traced values: NaN read as 0, everything clipped to [-1, 1])."""
        concrete = not isinstance(action, jax.core.Tracer)
        arr = np.asarray(action, dtype=np.float64) if concrete else action
        if tuple(np.shape(arr)) != self.action_shape:
            raise ValueError(f"{self.name}: action must have shape {self.action_shape} (one "
                             f"{'[acceleration, steering]' if self.action_size == 2 else 'value'} in [-1, 1] per "
                             f"controlled vehicle), got {tuple(np.shape(arr))}")
        if concrete and not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.name}: continuous actions must be finite, got {arr.tolist()}")
        a = jnp.asarray(action)
        if not jnp.issubdtype(a.dtype, jnp.floating):
            a = a.astype(jnp.float32)
        return jnp.clip(jnp.nan_to_num(a, nan=0.0, posinf=1.0, neginf=-1.0), -1.0, 1.0)


def store_continuous_actions(env, st, action, params):
    """``ContinuousAction.act`` of every controlled vehicle of ``env``: acceleration and steering stored in ``st``."""
    idx = jnp.asarray(env.controlled)
    dtype = st.x.dtype
    acc, steer = jax.vmap(lambda a: Veh.continuous_action(
        a.astype(dtype), env.longitudinal, env.lateral, params.acceleration_range,
        params.steering_range))(action)
    return st.replace(acceleration=st.acceleration.at[idx].set(acc.astype(dtype)),
                      steering=st.steering.at[idx].set(steer.astype(dtype)))
