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
from envs_jax import lanes as L
from envs_jax import vehicle as V
from envs_jax.road import Road

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


def sparse_map(fn, mask, *args):
    """``fn`` applied to the rows ``k`` of ``args`` (leading axis) where ``mask[k]``; zeros elsewhere.

    For work that is needed only rarely but would otherwise run for every
    environment under ``vmap`` (a batched ``cond`` evaluates both branches): the
    separating-axis test of vehicles that pass the bounding-circle prefilter, the
    next-lane choice of a vehicle at the end of its lane. Without ``vmap`` it is a
    ``cond`` on ``any(mask)``. Under ``vmap`` (custom batching rule) the masked rows
    of the whole batch are packed into chunks of a fixed capacity, ``fn`` runs on
    those only, and the results are scattered back; a ``while_loop`` over chunks
    keeps it exact whatever the number of masked rows. Rows are independent, so the
    result equals ``where(mask, vmap(fn)(*args), 0)`` up to XLA compiling ``fn``'s
    arithmetic differently (an ulp at most; tests/test_sparse_map.py).
    """
    vfn = jax.vmap(fn)

    def dense(mask, *args):
        out = jax.eval_shape(vfn, *args)
        zeros = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), out)
        res = jax.lax.cond(jnp.any(mask), lambda: vfn(*args), lambda: zeros)
        return jax.tree_util.tree_map(lambda r: jnp.where(mask.reshape(mask.shape + (1,) * (r.ndim - 1)), r, jnp.zeros_like(r)), res)

    f = jax.custom_batching.custom_vmap(dense)

    @f.def_vmap
    def rule(axis_size, in_batched, mask, *args):
        k = mask.shape[-1]
        n = axis_size * k  # rows of the whole batch, flattened
        flat = lambda a, b: (a if b else jnp.broadcast_to(a, (axis_size,) + a.shape)).reshape((n,) + a.shape[1 + b:])
        mask = flat(mask, in_batched[0])
        args = jax.tree_util.tree_map(flat, args, tuple(in_batched[1:]))
        cap = n if n <= 64 else max(64, n // 8)  # static chunk capacity
        pos = jnp.cumsum(mask.astype(jnp.int32)) - 1  # rank of each masked row
        count = jnp.sum(mask.astype(jnp.int32))
        out = jax.eval_shape(vfn, *args)
        out = jax.tree_util.tree_map(lambda s: jnp.zeros(s.shape, s.dtype), out)

        def chunk(carry):
            c, out = carry
            slot = pos - c * cap
            slot = jnp.where(mask & (slot >= 0) & (slot < cap), slot, cap)  # cap: dropped
            rows = jnp.full(cap, n, jnp.int32).at[slot].set(jnp.arange(n, dtype=jnp.int32), mode="drop")
            res = vfn(*jax.tree_util.tree_map(lambda a: a[jnp.minimum(rows, n - 1)], args))
            out = jax.tree_util.tree_map(lambda o, r: o.at[rows].set(r, mode="drop"), out, res)
            return c + 1, out

        _, out = jax.lax.while_loop(lambda carry: carry[0] * cap < count, chunk, (jnp.zeros((), jnp.int32), out))
        out = jax.tree_util.tree_map(lambda o: o.reshape((axis_size, k) + o.shape[1:]), out)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return f(mask, *args)


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
        # Local coordinates of each vehicle on every lane, reused by the controllers of the
        # next frame (the vehicles do not move between the lane update and the controllers).
        coords = self._locate(state.x, state.y, state.heading)[-1]
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
        steps_limit = jnp.ceil(params.duration * self.policy_frequency - 1e-6)
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
        vehicle's local coordinates ``(s[2, L], lat[2, L])`` on every lane."""
        cost, s_all, lat_all = L.distance_with_heading_all(self.road.lanes, x, y, heading)
        lane = L.first_argmin(cost)
        s = jnp.take_along_axis(s_all, lane[..., None], axis=-1)[..., 0]
        lat = jnp.take_along_axis(lat_all, lane[..., None], axis=-1)[..., 0]
        lengths = self.road.lanes.col("length")[lane]
        widths = self.road.lanes.col("width")[lane]
        return lane, s, lat, L.on_lane_coords(lengths, widths, s, lat), (s_all, lat_all)

    def _follow_road(self, st: EnvState, coords):
        """``ControlledVehicle.follow_road`` for both vehicles: past ``length - 2.5`` of the
        target lane, switch to ``next_lane``."""
        road = self.road
        lengths = road.lanes.col("length")

        tl, rp = st.target_lane, st.route_ptr
        s = jnp.take_along_axis(coords[0], tl[:, None], axis=-1)[:, 0]
        end = s > lengths[tl] - L.VEHICLE_LENGTH / 2
        # next_lane only for the (rare) vehicles at the end of their lane.
        nl, nrp = sparse_map(road.next_lane, end, tl, s, st.route_roads, st.route_ids, st.route_len, rp)
        return st.replace(target_lane=jnp.where(end, nl, tl), route_ptr=jnp.where(end, nrp, rp))

    def _decide_discrete(self, st: EnvState, coords, action, params):
        """First frame of a decision: ``follow_road`` then the meta-action (``MDPVehicle.act(a)``)."""
        st = self._follow_road(st, coords)
        ts = jnp.asarray(params.target_speeds)
        tl, si, tsp = jax.vmap(lambda a, tl, si, s_all, lat_all, v: V.meta_action(
            self.road, a, tl, si, s_all, lat_all, v, ts))(
            action, st.target_lane, st.speed_index, coords[0], coords[1], st.speed)
        return st.replace(target_lane=tl, speed_index=si, target_speed=tsp.astype(st.x.dtype))

    def _frame(self, st: EnvState, coords, obstacles, dt):
        """One simulation frame: controllers (``road.act``), kinematics (``road.step``), collisions."""
        if self.discrete:
            st = self._follow_road(st, coords)
            s_t = jnp.take_along_axis(coords[0], st.target_lane[:, None], axis=-1)[:, 0]
            lat_t = jnp.take_along_axis(coords[1], st.target_lane[:, None], axis=-1)[:, 0]
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
        """Static obstacles as collision shapes (corners computed once per step)."""
        obstacles = params.obstacles
        if obstacles is None or int(np.shape(obstacles)[0]) == 0:
            return []
        obstacles = jnp.asarray(obstacles, dtype)
        return [collision.Shape.make(o[0], o[1], o[2], 0.0, o[3], o[4]) for o in obstacles]

    def _collide(self, x, y, h, v, crashed, obstacles, dt):
        """``Road.step`` collision loop: vehicle pairs in road order, then each vehicle vs obstacles.

        Every check is ``collision.check``: the bounding-circle prefilter, then the
        separating-axis test, which ``sparse_map`` runs only for the pairs that pass
        the prefilter (a few percent of them); the others give no collision, as in
        highway-env. The results are applied in highway-env's order.
        """
        order = self.scenario.road_order
        shapes = [collision.Shape.make(x[i], y[i], h[i], v[i], V.LENGTH, V.WIDTH) for i in range(NUM_AGENTS)]
        checks = []  # (i, j or None for an obstacle, first shape, second shape)
        for k, i in enumerate(order):
            checks += [(i, j, shapes[i], shapes[j]) for j in order[k + 1:]]
            checks += [(i, None, shapes[i], ob) for ob in obstacles]
        near = jnp.stack([collision.near(a, b, dt) for _, _, a, b in checks])
        corners_a = jnp.stack([a.corners for _, _, a, _ in checks])
        corners_b = jnp.stack([b.corners for _, _, _, b in checks])
        disp_a = jnp.stack([jnp.stack([a.vx, a.vy]) * dt for _, _, a, _ in checks])
        disp_b = jnp.stack([jnp.stack([b.vx, b.vy]) * dt for _, _, _, b in checks])
        inter_all, will_all, trans_all = sparse_map(collision.polygons_intersecting, near,
                                                    corners_a, corners_b, disp_a, disp_b)
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

