"""Environment with V vehicle slots: K controlled agents and IDM/MOBIL background traffic.

Same API as :class:`envs_jax.env.DrivingEnv` (gymnax style)::

    obs, state = env.reset(key, params)
    obs, state, reward, cost, done, info = env.step(key, state, action, params)

with ``obs [K, vehicles_count, F]``, ``action [K]`` (discrete meta-actions),
``reward, cost [K]``, ``info["terminated"] [K]``, ``info["truncated"]`` and
``done = all(terminated) | truncated``. One step runs
``simulation_frequency // policy_frequency`` frames as highway-env's
``AbstractEnv._simulate``: the agents' meta-actions on the first frame only
(``MDPVehicle.act(action)``), then on every frame ``road.act()``
(:func:`envs_jax.drivers.road_act`), ``road.step(dt)`` (kinematics, lanes) and the
collision loop (:func:`envs_jax.pair_collisions.collide`), all in slot order =
highway-env's ``road.vehicles`` order.

A :class:`Task` provides the road, the slot layout and the spawn, reward and
termination rules; ``envs_jax/scenarios/highway.py`` is one.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import drivers, kinematic_obs, pair_collisions
from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from envs_jax import vehicle as Veh
from envs_jax.chunks import in_chunks
from envs_jax.idm import IDMParams
from envs_jax.road import Road
from envs_jax.time_limit import step_limit
from envs_jax.traffic_state import TrafficState


@struct.dataclass
class TrafficParams:
    """Numbers common to every traffic task (task params subclass this)."""

    duration: float = 40.0  # [s]
    collision_cost: float = 5.0  # cost per step while crashed (the authors' safety cost)
    target_speeds: Any = None  # MDP vehicles: the uniform target-speed grid
    idm: IDMParams = IDMParams()
    obstacles: Any = None  # [O, 5] rows x, y, heading, length, width (static solid objects)


class Task:
    """What a traffic task provides (see ``envs_jax/scenarios/highway.py``)."""

    name: str
    road: Road
    num_slots: int  # V
    controlled: tuple  # K slot indices, agent order
    simulation_frequency: int = 15
    policy_frequency: int = 1
    route_length: int = 1
    batch_chunk: int | None = None  # environments a batched step runs at once on the CPU (envs_jax/chunks.py)
    obs_config: kinematic_obs.KinematicsConfig = kinematic_obs.KinematicsConfig()
    check_collisions: Any = None  # static [V] flags (None: all)
    obs_range_lanes: Any = None  # static [K] lane counts of the default observation y range (None: current road)

    def default_params(self) -> TrafficParams:
        raise NotImplementedError

    def initial_vehicles(self, key, params) -> dict:
        """``x, y, heading, speed, alive, delta`` per slot (``[V]``), optionally ``routes``."""
        raise NotImplementedError

    def outcome(self, prev: TrafficState, state: TrafficState, action, params):
        """``(reward[K], cost[K], terminated[K], info)`` after a step (time limit excluded)."""
        raise NotImplementedError


class TrafficEnv:
    """A traffic task in pure JAX. Create with :func:`envs_jax.make`."""

    discrete = True

    def __init__(self, task: Task, default_params: TrafficParams):
        self.task = task
        self.name = task.name
        self.road = task.road
        self.simulation_frequency = int(task.simulation_frequency)
        self.policy_frequency = int(task.policy_frequency)
        self.frames = int(self.simulation_frequency // self.policy_frequency)
        self._default_params = default_params
        self.num_slots = int(task.num_slots)
        self.controlled = tuple(int(i) for i in task.controlled)
        self.num_agents = len(self.controlled)
        self.is_mdp = np.zeros(self.num_slots, bool)
        self.is_mdp[list(self.controlled)] = True
        self.is_idm = ~self.is_mdp
        check = task.check_collisions
        self.check_collisions = np.ones(self.num_slots, bool) if check is None else np.asarray(check, bool)
        self.obs_config = task.obs_config
        self.num_actions = len(Veh.ACTION_NAMES)
        self.action_shape = (self.num_agents,)
        self.obs_shape = (self.num_agents,) + self.obs_config.shape
        self._reset_jit = jax.jit(self._reset)
        step = in_chunks(lambda key, state, action, params: self._step(key, state, action, params, False),
                         task.batch_chunk)
        self._step_jit = jax.jit(step)
        self._substeps_jit = jax.jit(lambda key, state, action, params: self._step(key, state, action, params, True))

    def __repr__(self):
        return (f"TrafficEnv({self.name!r}, slots={self.num_slots}, controlled={self.controlled}, "
                f"frames={self.frames}, obs={self.obs_shape})")

    @property
    def default_params(self) -> TrafficParams:
        return self._default_params

    # ------------------------------------------------------------------------------------------
    def reset(self, key, params: TrafficParams | None = None):
        params = self._default_params if params is None else params
        return self._reset_jit(key, params)

    def _reset(self, key, params):
        key_init, key_obs = jax.random.split(key)
        init = self.task.initial_vehicles(key_init, params)
        return self.state_from(init, params, key_obs)

    def state_from(self, init: dict, params, key=None):
        """Observation and state from per-slot initial values (also used to inject states in tests).

        ``init``: ``x, y, heading, speed, alive, delta`` ``[V]``; optional ``target_speed``
        (MDP slots; default the speed), ``timer`` (IDM; default highway-env's
        ``(x + y) pi mod LANE_CHANGE_DELAY``) and ``routes`` ``(roads[V, R], ids[V, R], len[V])``.
        """
        dtype = L.float_dtype()
        x = jnp.asarray(init["x"], dtype)
        y = jnp.asarray(init["y"], dtype)
        heading = jnp.asarray(init["heading"], dtype) + jnp.zeros_like(x)
        speed = jnp.asarray(init["speed"], dtype) + jnp.zeros_like(x)
        alive = jnp.asarray(init["alive"], bool) & jnp.ones(x.shape, bool)
        lane, s, lat, _ = LL.locate(self.road.lanes, x, y, heading)
        on_road = L.on_lane_coords(self.road.lanes.col("length")[lane], self.road.lanes.col("width")[lane], s, lat)
        ts = jnp.asarray(params.target_speeds, dtype)
        target = init.get("target_speed")
        target = speed if target is None else jnp.asarray(target, dtype) + jnp.zeros_like(x)
        speed_index = jax.vmap(Veh.speed_to_index, in_axes=(0, None))(target, ts)
        mdp = jnp.asarray(self.is_mdp)
        target_speed = jnp.where(mdp, ts[speed_index], target)
        timer = init.get("timer")
        if timer is None:
            timer = jnp.mod((x + y) * jnp.pi, params.idm.lane_change_delay)
        timer = jnp.asarray(timer, dtype) + jnp.zeros_like(x)
        R = self.task.route_length
        routes = init.get("routes")
        if routes is None:
            route_roads = -jnp.ones((self.num_slots, R), jnp.int32)
            route_ids = -jnp.ones((self.num_slots, R), jnp.int32)
            route_len = jnp.zeros(self.num_slots, jnp.int32)
        else:
            route_roads, route_ids, route_len = (jnp.asarray(a, jnp.int32) for a in routes)
        zeros = jnp.zeros_like(x)
        state = TrafficState(
            x=x, y=y, heading=heading, speed=speed, alive=alive, crashed=jnp.zeros(x.shape, bool),
            on_road=on_road, lane=lane, target_lane=lane, target_speed=target_speed,
            speed_index=jnp.where(mdp, speed_index, 0), steering=zeros, acceleration=zeros,
            impact=jnp.zeros((self.num_slots, 2), dtype), has_impact=jnp.zeros(x.shape, bool),
            timer=timer, delta=jnp.asarray(init["delta"], dtype) + zeros,
            route_roads=route_roads, route_ids=route_ids, route_len=route_len,
            route_ptr=jnp.zeros(self.num_slots, jnp.int32), time=jnp.zeros((), jnp.int32))
        return self.observe(state, params, key), state

    def observe(self, state: TrafficState, params, key=None):
        return kinematic_obs.observe(self.obs_config, self.road, state, self.controlled,
                                     self._obstacles(params, state.x.dtype), key, self.task.obs_range_lanes)

    @staticmethod
    def _obstacles(params, dtype):
        ob = params.obstacles
        if ob is None or int(np.shape(ob)[0]) == 0:
            return None
        return jnp.asarray(ob, dtype)

    # ------------------------------------------------------------------------------------------
    def step(self, key, state: TrafficState, action, params: TrafficParams | None = None):
        """One policy step: ``obs, state, reward[K], cost[K], done, info``."""
        params = self._default_params if params is None else params
        obs, state, reward, cost, done, info, _ = self._step_jit(key, state, self.check_action(action), params)
        return obs, state, reward, cost, done, info

    def step_substeps(self, key, state: TrafficState, action, params: TrafficParams | None = None):
        """:meth:`step` plus the per-frame trajectory of every slot (``[frames, V]`` arrays)."""
        params = self._default_params if params is None else params
        return self._substeps_jit(key, state, self.check_action(action), params)

    def _decide(self, st: TrafficState, action, params):
        """``MDPVehicle.act(action)`` of the controlled slots (first frame): follow_road, meta-action."""
        idx = jnp.asarray(self.controlled)
        acting = jnp.zeros(self.num_slots, bool).at[idx].set(True)
        tl, rp = drivers.follow_road(self.road, st, acting)
        ts = jnp.asarray(params.target_speeds, st.x.dtype)
        circles = LL.circle_coords(self.road.lanes, st.x[idx], st.y[idx])
        new_tl, si, tsp = jax.vmap(lambda a, t, i, x, y, c, v: Veh.meta_action(self.road, a, t, i, x, y, c, v, ts))(
            action, tl[idx], st.speed_index[idx], st.x[idx], st.y[idx], circles, st.speed[idx])
        return st.replace(target_lane=tl.at[idx].set(new_tl), route_ptr=rp,
                          speed_index=st.speed_index.at[idx].set(si),
                          target_speed=st.target_speed.at[idx].set(tsp.astype(st.x.dtype)))

    def _frames(self, st: TrafficState, params, obstacles, dt, length: int, record=None):
        """``length`` frames in a scan, with ``record(st)`` of each (None: nothing). The slots' circle coordinates
        pass from each frame's lane search to the next frame's drivers (nothing moves in between)."""
        def frame(carry, _):
            st, circles = self._frame(*carry, params, obstacles, dt)
            return (st, circles), (record(st) if record else None)

        circles = LL.circle_coords(self.road.lanes, st.x, st.y)
        (st, _), trajectory = jax.lax.scan(frame, (st, circles), None, length=length)
        return st, trajectory

    def _frame(self, st: TrafficState, circles, params, obstacles, dt):
        """``road.act()`` then ``road.step(dt)``; ``circles``: the slots' :func:`~envs_jax.lane_locate.circle_coords`
        at their positions. Returns the state and the circle coordinates at the new positions."""
        st = drivers.road_act(self.road, st, self.is_idm, self.is_mdp, params.idm, obstacles, circles)
        return self._road_step(st, obstacles, dt)

    def _kinematics(self, st: TrafficState, dt):
        """Every slot's ``step(dt)``: ``(x, y, heading, speed, crashed, steering, acceleration)`` and a dict of
        further state fields it updates (none for ``Vehicle.step``)."""
        return Veh.bicycle_step(st.x, st.y, st.heading, st.speed, st.steering, st.acceleration, st.crashed,
                                st.impact[:, 0], st.impact[:, 1], st.has_impact, dt), {}

    def _road_step(self, st: TrafficState, obstacles, dt):
        """``road.step(dt)``: kinematics of the alive slots, their lanes, then the collision loop. Returns the state
        and the slots' circle coordinates at their new positions (from the lane search)."""
        (x, y, h, v, crashed, steering, acceleration), extra = self._kinematics(st, dt)
        alive = st.alive
        keep = lambda new, old: jnp.where(alive, new, old)
        x, y, h, v = keep(x, st.x), keep(y, st.y), keep(h, st.heading), keep(v, st.speed)
        crashed = keep(crashed, st.crashed)
        timer = jnp.where(alive & jnp.asarray(self.is_idm), st.timer + dt, st.timer)
        lane, s, lat, circles = LL.locate(self.road.lanes, x, y, h)
        lanes = self.road.lanes
        on_road = L.on_lane_coords(lanes.col("length")[lane], lanes.col("width")[lane], s, lat)
        lane, on_road = keep(lane, st.lane), keep(on_road, st.on_road)
        ob = None if obstacles is None else obstacles[:, :5]
        impact, has_impact, crashed = self._collide(st, x, y, h, v, alive, crashed, ob, dt)
        return st.replace(x=x, y=y, heading=h, speed=v, crashed=crashed, on_road=on_road, lane=lane,
                          steering=keep(steering, st.steering), acceleration=keep(acceleration, st.acceleration),
                          impact=impact, has_impact=has_impact, timer=timer,
                          **{k: keep(a, getattr(st, k)) for k, a in extra.items()}), circles

    def _collide(self, st, x, y, h, v, alive, crashed, obstacles, dt):
        """The collision loop over the slots in list order (= slot order here)."""
        return pair_collisions.collide(x, y, h, v, alive, crashed, self.check_collisions, obstacles, dt)

    def _step(self, key, state, action, params, record):
        prev = state
        dt = 1.0 / self.simulation_frequency
        obstacles = self._obstacles(params, state.x.dtype)
        state = self._decide(state, action, params)

        def rec(st):
            return dict(x=st.x, y=st.y, heading=st.heading, speed=st.speed, crashed=st.crashed, lane=st.lane,
                        target_lane=st.target_lane, on_road=st.on_road)

        state, trajectory = self._frames(state, params, obstacles, dt, self.frames, rec if record else None)
        state = state.replace(time=state.time + 1)
        obs = self.observe(state, params, key)
        reward, cost, terminated, info = self.task.outcome(prev, state, action, params)
        steps_limit = step_limit(params.duration, self.policy_frequency)
        truncated = state.time >= steps_limit
        done = jnp.all(terminated) | truncated
        idx = np.asarray(self.controlled)
        info = dict(info)
        info.update(terminated=terminated, truncated=truncated, crashed=state.crashed[idx],
                    on_road=state.on_road[idx])
        return obs, state, reward, cost, done, info, trajectory

    # ------------------------------------------------------------------------------------------
    def check_action(self, action):
        """Integers of shape ``[K]`` in ``0..4`` (``ValueError`` in eager use; traced values are clipped)."""
        concrete = not isinstance(action, jax.core.Tracer)
        arr = np.asarray(action) if concrete else action
        if tuple(np.shape(arr)) != self.action_shape:
            raise ValueError(f"{self.name}: action must have shape {self.action_shape} (one meta-action per "
                             f"controlled vehicle), got {tuple(np.shape(arr))}")
        if not jnp.issubdtype(arr.dtype, jnp.integer):
            raise ValueError(f"{self.name}: discrete actions must be integers in 0..4 {Veh.ACTION_NAMES}, "
                             f"got dtype {arr.dtype}")
        if concrete and (np.any(arr < 0) or np.any(arr > 4)):
            raise ValueError(f"{self.name}: discrete actions must be in 0..4 {Veh.ACTION_NAMES}, got {arr.tolist()}")
        return jnp.clip(jnp.asarray(action), 0, 4).astype(jnp.int32)
