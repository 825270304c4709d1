"""The two-agent driving environment: reset, step, substeps (gymnax-style API).

``obs, state = env.reset(key, params)`` and
``obs, state, reward, cost, done, info = env.step(key, state, action, params)``
are pure functions of fixed-shape arrays; ``vmap`` them over environments and
``jit`` the whole rollout. One policy step runs
``simulation_frequency // policy_frequency`` simulation frames exactly as
highway-env's ``AbstractEnv._simulate``: the decision is applied on the first
frame only, the low-level controllers run on every frame, then every vehicle
takes a kinematic step and collisions are resolved.

The scenario (road, initial state, reward, cost, termination) is a
:class:`Scenario`; the frequencies are static (they set the number of frames,
hence the program's shape) and everything else a user may change lives in the
``params`` pytree.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import collision, observation
from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from envs_jax import vehicle as V
from envs_jax.road import Road
from envs_jax.sparse import (
    sparse_map,  # also importable from here (envs_jax.env.sparse_map)
)
from envs_jax.time_limit import step_limit

NUM_AGENTS = 2


@struct.dataclass
class EnvParams:
    """Numbers common to every scenario (scenario params subclass this).

    ``init_*`` are per-agent (leader first). ``obstacles`` rows are
    ``[x, y, heading, length, width]`` of static solid 2x2 m objects.
    """

    duration: float = 20.0
    collision_cost: float = 5.0
    init_x: Any = None
    init_y: Any = None
    init_heading: Any = None
    init_speed: Any = None
    init_target_speed: Any = None  # MDP vehicles; None = the initial speed
    target_speeds: Any = None  # discrete (MDP) vehicles: the uniform target-speed grid
    obstacles: Any = None
    # continuous actions: [-1, 1] maps linearly onto these ranges (``ContinuousAction``)
    acceleration_range: Any = (-5.0, 5.0)  # m/s^2
    steering_range: Any = (-0.7853981633974483, 0.7853981633974483)  # rad, +-pi/4


@struct.dataclass
class EnvState:
    """Simulator state; per-vehicle arrays have shape ``[2]``, leader first."""

    x: jax.Array
    y: jax.Array
    heading: jax.Array
    speed: jax.Array
    crashed: jax.Array  # latched once a collision happened
    on_road: jax.Array  # on the closest lane (``vehicle.on_road``)
    lane: jax.Array  # closest lane, global index (``vehicle.lane_index``)
    lane_s: jax.Array  # local coordinates on ``lane``
    lane_lat: jax.Array
    target_lane: jax.Array  # lane followed by the steering controller (MDP vehicles)
    target_speed: jax.Array
    speed_index: jax.Array
    steering: jax.Array  # stored low-level action (held between decisions for plain vehicles)
    acceleration: jax.Array
    impact: jax.Array  # [2, 2] translation applied on the next frame
    has_impact: jax.Array
    route_roads: jax.Array  # [2, R] planned route (road indices), -1 padded
    route_ids: jax.Array  # [2, R] lane id per route step, -1 = any
    route_len: jax.Array
    route_ptr: jax.Array
    arrived: jax.Array  # scenario arrival flags
    first_arrived: jax.Array  # 0 nobody yet, 1 leader first, 2 follower first
    time: jax.Array  # policy steps taken


class Scenario:
    """What a scenario module provides; see ``envs_jax/scenarios/*.py``."""

    name: str
    discrete: bool = True
    longitudinal: bool = True  # continuous actions only
    lateral: bool = True
    road: Road
    road_order: tuple = (0, 1)  # order of ``road.vehicles`` (collision pairs, prefilter speed)
    simulation_frequency: int = 15
    policy_frequency: int = 1
    route_length: int = 1
    params_cls = EnvParams
    # env_config.json keys that the authors' multi-agent step never reads.
    inert_config_keys: frozenset = frozenset()

    def default_params(self) -> EnvParams:
        raise NotImplementedError

    def initial_vehicles(self, key, params) -> dict:
        """Per-vehicle initial ``x, y, heading, speed`` and (MDP) ``target_speed`` and routes."""
        raise NotImplementedError

    def outcome(self, prev: EnvState, state: EnvState, action, params):
        """``(reward[2], cost[2], terminated[2], state, info)`` after a step (time limit excluded)."""
        raise NotImplementedError


class DrivingEnv:
    """A two-agent highway-env scenario in pure JAX. Create with :func:`envs_jax.make`."""

    def __init__(self, scenario: Scenario, simulation_frequency: int, policy_frequency: int,
                 default_params: EnvParams):
        self.scenario = scenario
        self.name = scenario.name
        self.road = scenario.road
        self.simulation_frequency = int(simulation_frequency)
        self.policy_frequency = int(policy_frequency)
        self.frames = int(self.simulation_frequency // self.policy_frequency)
        self._default_params = default_params
        self.num_agents = NUM_AGENTS
        self.discrete = scenario.discrete
        self.num_actions = len(V.ACTION_NAMES) if self.discrete else None
        self.action_dim = None if self.discrete else int(scenario.longitudinal) + int(scenario.lateral)
        self.action_shape = (NUM_AGENTS,) if self.discrete else (NUM_AGENTS, self.action_dim)
        self.obs_shape = (NUM_AGENTS, 8)
        # Compiled once per shape and reused by eager calls; inlined when called under jit/vmap.
        self._reset_jit = jax.jit(self._reset)
        self._step_jit = jax.jit(lambda key, state, action, params: self._step(key, state, action, params, False))
        self._substeps_jit = jax.jit(lambda key, state, action, params: self._step(key, state, action, params, True))

    def __repr__(self):
        kind = "discrete(5)" if self.discrete else f"continuous({self.action_dim})"
        return (f"DrivingEnv({self.name!r}, actions={kind}, frames={self.frames}, "
                f"simulation_frequency={self.simulation_frequency}, policy_frequency={self.policy_frequency})")

    @property
    def default_params(self) -> EnvParams:
        return self._default_params

    # ------------------------------------------------------------------------------------------
    def reset(self, key, params: EnvParams | None = None):
        """Initial observation ``[2, 8]`` and state."""
        params = self._default_params if params is None else params
        return self._reset_jit(key, params)

    def _reset(self, key, params):
        init = self.scenario.initial_vehicles(key, params)
        x = jnp.asarray(init["x"])
        y = jnp.asarray(init["y"])
        heading = jnp.asarray(init["heading"]) + jnp.zeros_like(x)
        speed = jnp.asarray(init["speed"]) + jnp.zeros_like(x)
        lane, s, lat, on_road, _ = self._locate(x, y, heading)
        if self.discrete:
            ts = jnp.asarray(params.target_speeds)
            target = init.get("target_speed")
            target = speed if target is None else jnp.asarray(target) + jnp.zeros_like(x)
            speed_index = jax.vmap(V.speed_to_index, in_axes=(0, None))(target, ts)
            target_speed = ts[speed_index]
        else:
            speed_index = jnp.zeros(NUM_AGENTS, jnp.int32)
            target_speed = speed
        zeros = jnp.zeros_like(x)
        routes = init.get("routes")
        R = self.scenario.route_length
        if routes is None:
            route_roads = -jnp.ones((NUM_AGENTS, R), jnp.int32)
            route_ids = -jnp.ones((NUM_AGENTS, R), jnp.int32)
            route_len = jnp.zeros(NUM_AGENTS, jnp.int32)
        else:
            route_roads, route_ids, route_len = (jnp.asarray(a) for a in routes)
        state = EnvState(
            x=x, y=y, heading=heading, speed=speed,
            crashed=jnp.zeros(NUM_AGENTS, bool), on_road=on_road,
            lane=lane, lane_s=s, lane_lat=lat, target_lane=lane,
            target_speed=target_speed, speed_index=speed_index,
            steering=zeros, acceleration=zeros,
            impact=jnp.zeros((NUM_AGENTS, 2), x.dtype), has_impact=jnp.zeros(NUM_AGENTS, bool),
            route_roads=route_roads, route_ids=route_ids, route_len=route_len,
            route_ptr=jnp.zeros(NUM_AGENTS, jnp.int32),
            arrived=jnp.zeros(NUM_AGENTS, bool), first_arrived=jnp.zeros((), jnp.int32),
            time=jnp.zeros((), jnp.int32),
        )
        return self.observe(state), state

    def observe(self, state: EnvState):
        return observation.observe(state.x, state.y, state.heading, state.speed)

    # ------------------------------------------------------------------------------------------
    def step(self, key, state: EnvState, action, params: EnvParams | None = None):
        """One policy step. Returns ``obs, state, reward[2], cost[2], done, info``.

        ``info``: ``terminated[2]`` (crash / arrival / off-road, per agent),
        ``truncated`` (time limit), ``crashed[2]``, ``arrived[2]``, ``on_road[2]``
        and the scenario's own keys. ``done = all(terminated) | truncated``.
        """
        params = self._default_params if params is None else params
        action = self.check_action(action)
        obs, state, reward, cost, done, info, _ = self._step_jit(key, state, action, params)
        return obs, state, reward, cost, done, info

    def step_substeps(self, key, state: EnvState, action, params: EnvParams | None = None):
        """:meth:`step` plus the per-frame trajectory (``[frames, 2]`` arrays), for parity checks."""
        params = self._default_params if params is None else params
        return self._substeps_jit(key, state, self.check_action(action), params)

    def _step(self, key, state, action, params, record):
        prev = state
        dt = 1.0 / self.simulation_frequency
        # Polar coordinates of each vehicle around the circle centres (what the lane coordinates
        # need besides the position), reused by the controllers of the next frame (the vehicles
        # do not move between the lane update and the controllers).
        coords = LL.circle_coords(self.road.lanes, state.x, state.y)
        if self.discrete:
            state = self._decide_discrete(state, coords, action, params)
        else:
            acc, steer = jax.vmap(lambda a: V.continuous_action(
                a, self.scenario.longitudinal, self.scenario.lateral,
                params.acceleration_range, params.steering_range))(action)
            state = state.replace(acceleration=acc.astype(state.x.dtype), steering=steer.astype(state.x.dtype))

        obstacles = self._obstacle_shapes(params, state.x.dtype)

        def frame(carry, _):
            st, coords = carry
            st, coords = self._frame(st, coords, obstacles, dt)
            rec = (st.x, st.y, st.heading, st.speed, st.crashed, st.on_road, st.lane) if record else None
            return (st, coords), rec

        (state, _), trajectory = jax.lax.scan(frame, (state, coords), None, length=self.frames)
        state = state.replace(time=state.time + 1)
        obs = self.observe(state)
        reward, cost, terminated, state, info = self.scenario.outcome(prev, state, action, params)
        steps_limit = step_limit(params.duration, self.policy_frequency)
        truncated = state.time >= steps_limit
        done = jnp.all(terminated) | truncated
        info = dict(info)
        info.update(terminated=terminated, truncated=truncated, crashed=state.crashed,
                    arrived=state.arrived, on_road=state.on_road)
        if record:
            names = ("x", "y", "heading", "speed", "crashed", "on_road", "lane")
            trajectory = dict(zip(names, trajectory))
        return obs, state, reward, cost, done, info, trajectory

    # ------------------------------------------------------------------------------------------
    def _locate(self, x, y, heading):
        """Closest lane of each vehicle, its local coordinates and on-road flag, and the
        vehicles' polar coordinates around every circle centre (``LL.circle_coords``, ``[2, C]``
        each), from which ``LL.lane_coords`` gives the local coordinates on any lane."""
        lane, s, lat, coords = LL.locate(self.road.lanes, x, y, heading)
        lengths = self.road.lanes.col("length")[lane]
        widths = self.road.lanes.col("width")[lane]
        return lane, s, lat, L.on_lane_coords(lengths, widths, s, lat), coords

    def _follow_road(self, st: EnvState, coords):
        """``ControlledVehicle.follow_road`` for both vehicles: past ``length - 2.5`` of the
        target lane, switch to ``next_lane``."""
        road = self.road
        lengths = road.lanes.col("length")

        tl, rp = st.target_lane, st.route_ptr
        s, _ = LL.lane_coords(road.lanes, st.x, st.y, coords, tl)
        end = s > lengths[tl] - L.VEHICLE_LENGTH / 2
        # next_lane only for the (rare) vehicles at the end of their lane.
        nl, nrp = sparse_map(road.next_lane, end, tl, s, st.route_roads, st.route_ids, st.route_len, rp,
                             fraction=1 / 32)  # few vehicles reach a lane end in any one frame
        return st.replace(target_lane=jnp.where(end, nl, tl), route_ptr=jnp.where(end, nrp, rp))

    def _decide_discrete(self, st: EnvState, coords, action, params):
        """First frame of a decision: ``follow_road`` then the meta-action (``MDPVehicle.act(a)``)."""
        st = self._follow_road(st, coords)
        ts = jnp.asarray(params.target_speeds)
        tl, si, tsp = jax.vmap(lambda a, tl, si, x, y, c, v: V.meta_action(self.road, a, tl, si, x, y, c, v, ts))(
            action, st.target_lane, st.speed_index, st.x, st.y, coords, st.speed)
        return st.replace(target_lane=tl, speed_index=si, target_speed=tsp.astype(st.x.dtype))

    def _frame(self, st: EnvState, coords, obstacles, dt):
        """One simulation frame: controllers (``road.act``), kinematics (``road.step``), collisions."""
        if self.discrete:
            st = self._follow_road(st, coords)
            s_t, lat_t = LL.lane_coords(self.road.lanes, st.x, st.y, coords, st.target_lane)
            steering = jax.vmap(lambda tl, s, lat, h, v: V.steering_control(self.road.lanes, tl, s, lat, h, v))(
                st.target_lane, s_t, lat_t, st.heading, st.speed)
            acceleration = V.speed_control(st.target_speed, st.speed)
            st = st.replace(steering=steering, acceleration=acceleration)
        x, y, h, v, crashed, steering, acceleration = V.bicycle_step(
            st.x, st.y, st.heading, st.speed, st.steering, st.acceleration, st.crashed,
            st.impact[:, 0], st.impact[:, 1], st.has_impact, dt)
        lane, s, lat, on_road, coords = self._locate(x, y, h)
        impact, has_impact, crashed = self._collide(x, y, h, v, crashed, obstacles, dt)
        st = st.replace(x=x, y=y, heading=h, speed=v, crashed=crashed, steering=steering,
                        acceleration=acceleration, lane=lane, lane_s=s, lane_lat=lat, on_road=on_road,
                        impact=impact, has_impact=has_impact)
        return st, coords

    @staticmethod
    def _obstacle_shapes(params, dtype):
        """Static obstacles as collision poses ``(x, y, heading, speed=0, length, width)``."""
        obstacles = params.obstacles
        if obstacles is None or int(np.shape(obstacles)[0]) == 0:
            return []
        obstacles = jnp.asarray(obstacles, dtype)
        return [(o[0], o[1], o[2], jnp.zeros((), dtype), o[3], o[4]) for o in obstacles]

    def _collide(self, x, y, h, v, crashed, obstacles, dt):
        """``Road.step`` collision loop: vehicle pairs in road order, then each vehicle vs obstacles.

        Every check is ``collision.check``: the bounding-circle prefilter, then the
        separating-axis test, which ``sparse_map`` runs only for the pairs that pass
        the prefilter (a few percent of them); the others give no collision, as in
        highway-env. The rectangles' corners and velocities (a sine and a cosine per
        object) are computed inside, for those pairs only. The results are applied in
        highway-env's order.
        """
        order = self.scenario.road_order
        dtype = x.dtype
        poses = [(x[i], y[i], h[i], v[i], jnp.asarray(V.LENGTH, dtype), jnp.asarray(V.WIDTH, dtype))
                 for i in range(NUM_AGENTS)]
        checks = []  # (i, j or None for an obstacle, first pose, second pose)
        for k, i in enumerate(order):
            checks += [(i, j, poses[i], poses[j]) for j in order[k + 1:]]
            checks += [(i, None, poses[i], ob) for ob in obstacles]
        # the prefilter needs only centres, speeds and diagonals (XLA drops the unused corners)
        near = jnp.stack([collision.near(collision.Shape.make(*a), collision.Shape.make(*b), dt)
                          for _, _, a, b in checks])
        pose_a = jnp.stack([jnp.stack(a) for _, _, a, _ in checks])  # [checks, 6]
        pose_b = jnp.stack([jnp.stack(b) for _, _, _, b in checks])

        def separating_axis(pa, pb):
            a, b = collision.Shape.make(*pa), collision.Shape.make(*pb)
            disp_a = jnp.stack([a.vx, a.vy]) * dt
            disp_b = jnp.stack([b.vx, b.vy]) * dt
            return collision.polygons_intersecting(a.corners, b.corners, disp_a, disp_b)

        # few pairs pass the prefilter (docs/performance.md)
        inter_all, will_all, trans_all = sparse_map(separating_axis, near, pose_a, pose_b, fraction=1 / 32)
        impact = [jnp.zeros(2, x.dtype) for _ in range(NUM_AGENTS)]
        has = [jnp.zeros((), bool) for _ in range(NUM_AGENTS)]
        crash = [crashed[i] for i in range(NUM_AGENTS)]
        for c, (i, j, _, _) in enumerate(checks):
            inter, will, t = inter_all[c], will_all[c], trans_all[c]
            if j is None:
                impact[i] = jnp.where(will, t, impact[i])
            else:
                impact[i] = jnp.where(will, t / 2, impact[i])
                impact[j] = jnp.where(will, -t / 2, impact[j])
                has[j] = has[j] | will
                crash[j] = crash[j] | inter
            has[i] = has[i] | will
            crash[i] = crash[i] | inter
        return jnp.stack(impact), jnp.stack(has), jnp.stack(crash)

    # ------------------------------------------------------------------------------------------
    def check_action(self, action):
        """Validate an action at the Python boundary; inside ``jit`` only shape and dtype are checked.

        Discrete: integers of shape ``[2]`` in ``0..4`` (traced values are clipped).
        Continuous: floats of shape ``[2, action_dim]`` (or ``[2]`` when action_dim is 1),
        finite in eager use; traced values are clipped to [-1, 1] with NaN read as 0.
        """
        concrete = not isinstance(action, jax.core.Tracer)
        if self.discrete:
            arr = action if not concrete else np.asarray(action)
            if tuple(np.shape(arr)) != self.action_shape:
                raise ValueError(f"{self.name}: action must have shape {self.action_shape} "
                                 f"(leader, follower), got {tuple(np.shape(arr))}")
            if not jnp.issubdtype(arr.dtype, jnp.integer):
                raise ValueError(f"{self.name}: discrete actions must be integers in 0..4 "
                                 f"{V.ACTION_NAMES}, got dtype {arr.dtype}")
            if concrete and (np.any(arr < 0) or np.any(arr > 4)):
                raise ValueError(f"{self.name}: discrete actions must be in 0..4 {V.ACTION_NAMES}, got {arr.tolist()}")
            return jnp.clip(jnp.asarray(action), 0, 4).astype(jnp.int32)
        arr = action if not concrete else np.asarray(action)
        shape = tuple(np.shape(arr))
        if self.action_dim == 1 and shape == (NUM_AGENTS,):
            action = jnp.asarray(action)[:, None]
            arr = arr[:, None] if concrete else action
            shape = (NUM_AGENTS, 1)
        if shape != self.action_shape:
            raise ValueError(f"{self.name}: action must have shape {self.action_shape} (leader, follower)"
                             f"{' or (2,)' if self.action_dim == 1 else ''}, got {shape}")
        if not jnp.issubdtype(arr.dtype, jnp.floating):
            raise ValueError(f"{self.name}: continuous actions must be floats in [-1, 1], got dtype {arr.dtype}")
        if concrete and not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.name}: continuous actions must be finite, got {np.asarray(arr).tolist()}")
        action = jnp.asarray(action)
        return jnp.clip(jnp.nan_to_num(action, nan=0.0), -1.0, 1.0)

