"""``intersection-v1`` (highway-env ``ContinuousIntersectionEnv``): the intersection with dynamical agents.

Everything of :mod:`envs_jax.scenarios.intersection_traffic` (road, right of way, initial
vehicles, warm-up, challenger, spawns, clears, rewards, termination, the slot pool) except
the controlled vehicles, which are highway-env's ``ContinuousAction(dynamical=True)``
vehicle, a ``BicycleVehicle`` (:mod:`envs_jax.dynamics`):

* an action ``[K, d]`` in ``[-1, 1]`` (``d`` = 2: acceleration in +-5 m/s^2, steering in
  +-pi/3 rad by default) is stored on the first frame of a step and held;
* each frame moves them by one Runge-Kutta step of the dynamical bicycle, with their
  lateral speed and yaw rate as extra state (``ContinuousIntersectionState``); a collision
  marks them crashed but its impact does not move them (``BicycleVehicle.step`` ignores it);
* they have no route (``plan_route_to`` does not exist on that class), so their destination
  direction is zero, and the regulation predicts them by stepping a copy of the dynamics
  with zero acceleration and the stored steering (``Vehicle.predict_trajectory_constant_speed``),
  not along a route. They never yield (they are not ``ControlledVehicle`` s).

Default observation: Kinematics of 5 vehicles with ``presence, x, y, vx, vy, long_off, lat_off,
ang_off`` (absolute, x/y in +-100 m, vx/vy in +-20 m/s). ``vx, vy`` are ``speed`` along the
heading, as highway-env's ``velocity`` (the lateral speed is not in it).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import dynamics, regulation
from envs_jax.continuous_traffic_env import ContinuousTrafficEnv, store_continuous_actions
from envs_jax.scenarios.config_values import config_given, continuous_action_config
from envs_jax.scenarios.intersection_traffic import (
    DEFAULTS,
    OWN_KEYS,
    TARGET_SPEEDS,
    IntersectionState,
    IntersectionTraffic,
    IntersectionTrafficEnv,
    IntersectionTrafficParams,
    intersection_settings,
)

NAME = "intersection-v1"
OBSERVATION = {"type": "Kinematics", "vehicles_count": 5,
               "features": ["presence", "x", "y", "vx", "vy", "long_off", "lat_off", "ang_off"],
               "features_range": {"x": [-100, 100], "y": [-100, 100], "vx": [-20, 20], "vy": [-20, 20]},
               "absolute": True, "observe_intentions": False}
ACTION = {"type": "ContinuousAction", "steering_range": [-np.pi / 3, np.pi / 3], "longitudinal": True,
          "lateral": True, "dynamical": True, "target_speeds": list(TARGET_SPEEDS)}
# is_conflict_possible steps its copy by the differences of its prediction times (all equal)
PREDICTION_DT = np.diff(np.concatenate(([0.0], regulation.PREDICTION_TIMES)))
assert np.all(PREDICTION_DT == PREDICTION_DT[0])


@struct.dataclass
class ContinuousIntersectionParams(IntersectionTrafficParams):
    acceleration_range: Any = (-5.0, 5.0)
    steering_range: Any = (-np.pi / 3, np.pi / 3)


@struct.dataclass
class ContinuousIntersectionState(IntersectionState):
    lateral_speed: jax.Array  # [V] body-frame lateral speed of the agents (0 for the IDM slots)
    yaw_rate: jax.Array  # [V] of the agents (0 for the IDM slots)


class ContinuousIntersection(IntersectionTraffic):
    """The intersection task whose agents are ``BicycleVehicle`` s."""

    def __init__(self, name: str, longitudinal: bool, lateral: bool, **kwargs):
        super().__init__(name, **kwargs)
        self.longitudinal, self.lateral = longitudinal, lateral

    def empty_state(self, params) -> ContinuousIntersectionState:
        base = super().empty_state(params)
        zero = jnp.zeros_like(base.x)
        fields = {f.name: getattr(base, f.name) for f in dataclasses.fields(base)}
        return ContinuousIntersectionState(**fields, lateral_speed=zero, yaw_rate=zero)

    def place_agents(self, st, z_ego, destination, params):
        """The agents as in ``intersection-v0``, without a route or a target speed (a ``BicycleVehicle``
        has neither), lateral speed and yaw rate 0."""
        st = super().place_agents(st, z_ego, destination, params)
        ctrl = jnp.asarray(self.is_controlled)
        return st.replace(route_len=jnp.where(ctrl, 0, st.route_len), route_ptr=jnp.where(ctrl, 0, st.route_ptr),
                          speed_index=jnp.where(ctrl, 0, st.speed_index),
                          target_speed=jnp.where(ctrl, 0.0, st.target_speed).astype(st.x.dtype),
                          lateral_speed=jnp.where(ctrl, 0.0, st.lateral_speed).astype(st.x.dtype),
                          yaw_rate=jnp.where(ctrl, 0.0, st.yaw_rate).astype(st.x.dtype))


class ContinuousIntersectionEnv(IntersectionTrafficEnv):
    """:class:`IntersectionTrafficEnv` with continuous-action ``BicycleVehicle`` agents."""

    discrete = False
    action_names = None
    check_action = ContinuousTrafficEnv.check_action  # floats [K, d] in [-1, 1]

    def __init__(self, task: ContinuousIntersection, default_params):
        self.longitudinal, self.lateral = bool(task.longitudinal), bool(task.lateral)
        self.action_size = int(self.longitudinal) + int(self.lateral)
        super().__init__(task, default_params)
        # the agents are neither MDP nor IDM drivers: road.act leaves them alone and they never yield
        self.is_mdp = np.zeros(self.num_slots, bool)
        self.is_idm = ~np.asarray(task.is_controlled)
        self.num_actions = None
        self.action_shape = (self.num_agents, self.action_size)

    def __repr__(self):
        return (f"ContinuousIntersectionEnv({self.name!r}, slots={self.num_slots}, controlled={self.controlled}, "
                f"frames={self.frames}, action={self.action_shape}, obs={self.obs_shape})")

    def _act(self, st, action, params):
        """``ContinuousAction.act`` of every agent: store its acceleration and steering."""
        return store_continuous_actions(self, st, action, params)

    def _kinematics(self, st, dt):
        """``Vehicle.step`` for the IDM slots, ``BicycleVehicle.step`` for the agents."""
        (x, y, h, v, crashed, steering, acceleration), _ = super()._kinematics(st, dt)
        idx = jnp.asarray(self.controlled)
        nx, ny, nh, nv, nl, nr, ns, na = dynamics.step(
            st.x[idx], st.y[idx], st.heading[idx], st.speed[idx], st.lateral_speed[idx], st.yaw_rate[idx],
            st.steering[idx], st.acceleration[idx], st.crashed[idx], dt)
        put = lambda a, b: a.at[idx].set(b.astype(a.dtype))
        out = (put(x, nx), put(y, ny), put(h, nh), put(v, nv), crashed.at[idx].set(st.crashed[idx]),
               put(steering, ns), put(acceleration, na))
        return out, dict(lateral_speed=put(st.lateral_speed, nl), yaw_rate=put(st.yaw_rate, nr))

    def _predictions(self, st):
        """Every IDM slot along its route; the agents by their own dynamics, zero acceleration, steering held."""
        times = jnp.asarray(regulation.PREDICTION_TIMES, st.x.dtype)
        px, py, ph = regulation.predict_along_route(self.road, st, times)
        idx = jnp.asarray(self.controlled)
        ax, ay, ah = dynamics.predict_constant_steering(
            st.x[idx], st.y[idx], st.heading[idx], st.speed[idx], st.lateral_speed[idx], st.yaw_rate[idx],
            st.steering[idx], st.crashed[idx], float(PREDICTION_DT[0]), len(regulation.PREDICTION_TIMES))
        put = lambda a, b: a.at[idx].set(b.astype(a.dtype))
        return put(px, ax), put(py, ay), put(ph, ah)

    def _record(self, st):
        return dict(super()._record(st), lateral_speed=st.lateral_speed, yaw_rate=st.yaw_rate)


def make_intersection_continuous(name: str = NAME, env_config: dict | None = None,
                                 **overrides) -> ContinuousIntersectionEnv:
    """``intersection-v1`` from highway-env's config keys (``env_config`` and/or keywords).

    The keys of :func:`~envs_jax.scenarios.intersection_traffic.make_intersection` (``controlled_vehicles``
    for K agents, ``duration``, ``destination``, ``spawn_probability``, the reward keys, ``observation``,
    ``num_slots``, ``collision_cost``, ``idm``, ...), with ``action`` a ``ContinuousAction`` section
    (``dynamical`` must be True: the ``BicycleVehicle``). Unknown keys or bad values raise ``ValueError``
    naming them and what is allowed.
    """
    cfg = dict(DEFAULTS["intersection-v0"])
    cfg["observation"] = dict(OBSERVATION)
    cfg["action"] = dict(ACTION)
    cfg.update(config_given(name, cfg, OWN_KEYS, env_config, overrides, "allowed: False"))
    task, params = intersection_settings(name, cfg)
    lon, lat, action = continuous_action_config(name, cfg["action"], True, list(TARGET_SPEEDS))
    return ContinuousIntersectionEnv(ContinuousIntersection(name, lon, lat, **task),
                                     ContinuousIntersectionParams(**params, **action))
