"""``intersection-v0`` and ``intersection-multi-agent-v0`` (highway-env ``envs/intersection_env.py``) with traffic.

The four-way junction of :func:`envs_jax.scenarios.intersection.build_road` with
highway-env's lane priorities (3 for the horizontal arms' straight lanes and right
turns, 1 for the vertical ones, one less for left turns) under the right-of-way
rules of :mod:`envs_jax.regulation`. Vehicles live in a fixed pool of slots: the K
controlled vehicles in slots ``0..K-1`` (agent k on arm ``k % 4``), IDM drivers in
the others (``alive`` marks the occupied ones). The IDM drivers use the env's
constants (jam distance 7 m, comfort accelerations +6 / -3 m/s^2).

Reset (``_make_vehicles``): ``initial_vehicle_count - 1`` spawn attempts at
``linspace(0, 80, n)[t]`` metres, a 3 s warm-up of the road without the agents,
the challenger (a sure spawn at 60 m that goes straight), then the agents at
``60 + 5 N(1, 1)`` metres along their arm at 10 m/s, each removing the IDM vehicles
closer than 20 m. Each step, after the outcome: ``_clear_vehicles`` (IDM vehicles
on an exit lane within ``4 x 5`` m of its end leave), then a spawn attempt with
``spawn_probability``. A spawn: a random arm and a different random exit, 5 m
(+ N(0, 1) m) along the arm at 8 (+ N(0, 1)) m/s, a random IDM exponent; dropped
when a vehicle is closer than 15 m (highway-env's rule), and also, here, when no
slot is free (``info["pool_full"]``, counted in ``state.spawn_skipped``; a live
vehicle is never overwritten). The default pool cannot be exceeded by the default
episode: ``K + initial_vehicle_count + steps`` slots.

Per agent: reward ``-5 crashed + clip((speed - 7) / 2, 0, 1)``, or ``arrived_reward``
once on its exit lane 25 m past the junction, times on-road; cost
``collision_cost * crashed``; terminated when crashed or arrived; the 13 s time
limit truncates. ``info["env_terminated"]`` is highway-env's episode flag (any
agent crashed or all arrived).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import drivers, kinematic_obs, pair_collisions, regulation
from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from envs_jax import vehicle as Veh
from envs_jax.idm import IDMParams
from envs_jax.scenarios.config_values import (
    config_given,
    cost_value,
    flag_value,
    idm_params,
    int_value,
    number_value,
    observation_config,
    speed_range,
    unwrap_section,
)
from envs_jax.scenarios.intersection import build_road
from envs_jax.sparse import sparse_map
from envs_jax.time_limit import step_limit
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams
from envs_jax.traffic_state import TrafficState

ACTIONS = ("SLOWER", "IDLE", "FASTER")  # DiscreteMetaAction(lateral=False)
META_INDEX = np.array([4, 1, 3], np.int32)  # their indices in vehicle.ACTION_NAMES
SPAWN_CLEARANCE = 15.0  # [m] a spawn is dropped when a vehicle is closer
EGO_CLEARANCE = 20.0  # [m] IDM vehicles closer to a new agent are removed
EXIT_DISTANCE = 25.0  # [m] has_arrived's exit_distance
WARMUP_SECONDS = 3
RULES_FRACTION = 1 / 4  # above the share of environments whose regulation is due on a frame (1 / period)

DEFAULTS = {
    "intersection-v0": dict(simulation_frequency=15, policy_frequency=1, duration=13, destination="o1",
                            controlled_vehicles=1, initial_vehicle_count=10, spawn_probability=0.6,
                            collision_reward=-5, high_speed_reward=1, arrived_reward=1,
                            reward_speed_range=[7.0, 9.0], normalize_reward=False, offroad_terminal=False),
}
DEFAULTS["intersection-multi-agent-v0"] = dict(DEFAULTS["intersection-v0"], controlled_vehicles=2)
OBSERVATION = {"type": "Kinematics", "vehicles_count": 15,
               "features": ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h"],
               "features_range": {"x": [-100, 100], "y": [-100, 100], "vx": [-20, 20], "vy": [-20, 20]},
               "absolute": True, "observe_intentions": False}
TARGET_SPEEDS = (0.0, 4.5, 9.0)
OWN_KEYS = ("num_slots", "collision_cost", "idm", "on_road_reward")


def intersection_idm() -> IDMParams:
    """``IDMVehicle`` with the env's overrides (``DISTANCE_WANTED = 7``, ``COMFORT_ACC_MAX = 6``, ``_MIN = -3``)."""
    return IDMParams(distance_wanted=7.0, comfort_acc_max=6.0, comfort_acc_min=-3.0)


@struct.dataclass
class IntersectionTrafficParams(TrafficParams):
    spawn_probability: float = 0.6
    destination: int = 1  # exit arm of the agents (o<d>); -1: random in 1..3 per agent
    collision_reward: float = -5.0
    high_speed_reward: float = 1.0
    arrived_reward: float = 1.0
    on_road_reward: float = 0.0  # highway-env's config.get("on_road_reward", 0)
    reward_speed_range: Any = (7.0, 9.0)
    normalize_reward: bool = False
    offroad_terminal: bool = False


@struct.dataclass
class IntersectionState(TrafficState):
    yielding: jax.Array  # [V] stopped by the regulation
    yield_timer: jax.Array  # [V] regulation checks since it yielded
    road_steps: jax.Array  # road.step calls since the road was made (warm-up included)
    spawn_skipped: jax.Array  # spawns dropped because the pool was full (episode total)
    order: jax.Array  # [V] position in highway-env's road.vehicles list (insertion counter)
    next_order: jax.Array  # the counter


def shortest_path(roads, start: str, goal: str) -> list:
    """``RoadNetwork.shortest_path``: the first path of its breadth-first search (sorted successors)."""
    graph: dict = {}
    for f, t in roads:
        graph.setdefault(f, []).append(t)
    queue = [(start, [start])]
    while queue:
        node, path = queue.pop(0)
        if node not in graph:
            return []
        for nxt in sorted(t for t in graph[node] if t not in path):
            if nxt == goal:
                return path + [nxt]
            if nxt in graph:
                queue.append((nxt, path + [nxt]))
    return []


def lane_priorities(road) -> np.ndarray:
    """Per lane: 3 on the horizontal arms (corners 1, 3), 1 on the vertical ones, minus 1 for left turns."""
    out = np.zeros(len(road.lane_names), np.int32)
    for corner in range(4):
        p = 3 if corner % 2 else 1
        names = [(f"o{corner}", f"ir{corner}", p), (f"ir{corner}", f"il{(corner - 1) % 4}", p),
                 (f"ir{corner}", f"il{(corner + 1) % 4}", p - 1), (f"ir{corner}", f"il{(corner + 2) % 4}", p),
                 (f"il{(corner - 1) % 4}", f"o{(corner - 1) % 4}", p)]
        for f, t, prio in names:
            out[road.lane(f, t, 0)] = prio
    return out


class IntersectionTraffic(Task):
    """The intersection task for a given static layout."""

    simulation_frequency = 15
    policy_frequency = 1

    def __init__(self, name: str, controlled_vehicles: int, initial_vehicle_count: int, num_slots: int,
                 simulation_frequency: int, policy_frequency: int, obs_config: kinematic_obs.KinematicsConfig):
        self.name = name
        self.road = build_road()
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.obs_config = obs_config
        self.num_slots = num_slots
        self.controlled = tuple(range(controlled_vehicles))
        self.initial_vehicle_count = initial_vehicle_count
        self.priority = lane_priorities(self.road)
        road = self.road
        self.arm_lane = np.array([road.lane(f"o{a}", f"ir{a}", 0) for a in range(4)], np.int32)
        self.is_exit = np.array(["il" in f and "o" in t for f, t, _ in road.lane_names])
        # routes[a, d]: plan_route_to(f"o{d}") from arm a's incoming lane
        nodes = {(a, d): [f"o{a}"] + shortest_path(road.roads, f"ir{a}", f"o{d}") for a in range(4) for d in range(4)}
        self.route_length = max(len(n) - 1 if len(n) > 1 else 1 for n in nodes.values())
        shape = (4, 4, self.route_length)
        self.route_roads = np.full(shape, -1, np.int32)
        self.route_ids = np.full(shape, -1, np.int32)
        self.route_len = np.zeros((4, 4), np.int32)
        for (a, d), n in nodes.items():
            if len(n) < 2:  # no path: the route is the incoming lane alone
                n = [f"o{a}", f"ir{a}"]
            r, i, k = road.route(n, first_lane_id=0, length=self.route_length)
            self.route_roads[a, d], self.route_ids[a, d], self.route_len[a, d] = r, i, k
        self.is_controlled = np.zeros(num_slots, bool)
        self.is_controlled[list(self.controlled)] = True
        self.warmup_frames = WARMUP_SECONDS * simulation_frequency
        self.period = regulation.regulation_period(simulation_frequency)

    # -- random draws ------------------------------------------------------------------------
    @staticmethod
    def spawn_draws(key, n: int, dtype) -> dict:
        """The draws of ``n`` spawn attempts, in ``_spawn_vehicle``'s order: ``u`` (the spawn test),
        ``route`` (arm, exit: two different arms), ``z_position``, ``z_speed`` (standard normals) and
        ``u_delta`` (``randomize_behavior``'s uniform)."""
        k_u, k_a, k_e, k_p, k_s, k_d = jax.random.split(key, 6)
        arm = jax.random.randint(k_a, (n,), 0, 4)
        exit_arm = (arm + jax.random.randint(k_e, (n,), 1, 4)) % 4  # uniform over the ordered pairs, as choice
        route = jnp.stack([arm, exit_arm], axis=-1).astype(jnp.int32)
        return dict(u=jax.random.uniform(k_u, (n,), dtype), route=route,
                    z_position=jax.random.normal(k_p, (n,), dtype), z_speed=jax.random.normal(k_s, (n,), dtype),
                    u_delta=jax.random.uniform(k_d, (n,), dtype))

    def reset_draws(self, key, params) -> dict:
        """Every random number of a reset: ``initial`` (the ``initial_vehicle_count - 1`` attempts),
        ``challenger`` (one attempt), the agents' ``z_ego`` (``N(1, 1) - 1``) and ``destination`` (1..3,
        used when ``params.destination < 0``)."""
        dtype = L.float_dtype()
        k_i, k_c, k_e, k_d = jax.random.split(key, 4)
        k = len(self.controlled)
        return dict(initial=self.spawn_draws(k_i, self.initial_vehicle_count - 1, dtype),
                    challenger=self.spawn_draws(k_c, 1, dtype),
                    z_ego=jax.random.normal(k_e, (k,), dtype),
                    destination=jax.random.randint(k_d, (k,), 1, 4))

    # -- vehicles ----------------------------------------------------------------------------
    def empty_state(self, params) -> IntersectionState:
        dtype = L.float_dtype()
        v, r = self.num_slots, self.route_length
        zf = jnp.zeros(v, dtype)
        zb = jnp.zeros(v, bool)
        zi = jnp.zeros(v, jnp.int32)
        return IntersectionState(
            x=zf, y=zf, heading=zf, speed=zf, alive=zb, crashed=zb, on_road=zb, lane=zi, target_lane=zi,
            target_speed=zf, speed_index=zi, steering=zf, acceleration=zf, impact=jnp.zeros((v, 2), dtype),
            has_impact=zb, timer=zf, delta=zf + params.idm.delta, route_roads=-jnp.ones((v, r), jnp.int32),
            route_ids=-jnp.ones((v, r), jnp.int32), route_len=zi, route_ptr=zi, time=jnp.zeros((), jnp.int32),
            yielding=zb, yield_timer=zi, road_steps=jnp.zeros((), jnp.int32),
            spawn_skipped=jnp.zeros((), jnp.int32), order=zi, next_order=jnp.zeros((), jnp.int32))

    def put(self, st: IntersectionState, where, x, y, heading, speed, target_speed, delta, arm, dest, params):
        """A new vehicle (highway-env's constructor state) in the slot flagged by ``where`` ``[V]`` (none or one),
        appended to the list."""
        lanes = self.road.lanes
        v = self.num_slots
        bx = lambda a: jnp.broadcast_to(jnp.asarray(a, st.x.dtype), (v,))
        # the closest lane of the new poses only (one, or one per agent), then spread over the slots
        pose = [jnp.atleast_1d(jnp.asarray(a, st.x.dtype)) for a in (x, y, heading)]
        lane, s, lat, _ = LL.locate(lanes, *pose)
        on_road = L.on_lane_coords(lanes.col("length")[lane], lanes.col("width")[lane], s, lat)
        lane, on_road = jnp.broadcast_to(lane, (v,)), jnp.broadcast_to(on_road, (v,))
        x, y, heading = bx(x), bx(y), bx(heading)
        timer = jnp.mod((x + y) * jnp.pi, params.idm.lane_change_delay)
        rr = jnp.asarray(self.route_roads)[arm, dest]
        ri = jnp.asarray(self.route_ids)[arm, dest]
        rl = jnp.asarray(self.route_len)[arm, dest]
        w = lambda new, old: jnp.where(where.reshape((v,) + (1,) * (old.ndim - 1)),
                                       jnp.broadcast_to(jnp.asarray(new, old.dtype), old.shape), old)
        zero = jnp.zeros_like(st.x)
        return st.replace(
            x=w(x, st.x), y=w(y, st.y), heading=w(heading, st.heading), speed=w(bx(speed), st.speed),
            alive=st.alive | where, crashed=w(False, st.crashed), on_road=w(on_road, st.on_road),
            lane=w(lane, st.lane), target_lane=w(lane, st.target_lane),
            target_speed=w(bx(target_speed), st.target_speed),
            speed_index=w(0, st.speed_index), steering=w(zero, st.steering), acceleration=w(zero, st.acceleration),
            impact=w(jnp.zeros_like(st.impact), st.impact), has_impact=w(False, st.has_impact),
            timer=w(timer, st.timer), delta=w(bx(delta), st.delta), route_roads=w(rr, st.route_roads),
            route_ids=w(ri, st.route_ids), route_len=w(rl, st.route_len), route_ptr=w(0, st.route_ptr),
            yielding=w(False, st.yielding), yield_timer=w(0, st.yield_timer),
            order=w(st.next_order + jnp.cumsum(where) - 1, st.order),
            next_order=st.next_order + jnp.sum(where).astype(jnp.int32))

    def spawn(self, st: IntersectionState, d: dict, params, longitudinal=0.0, position_deviation=1.0,
              speed_deviation=1.0, probability=None, go_straight=False):
        """``_spawn_vehicle`` with the draws ``d`` (one attempt); returns ``(state, events)``."""
        lanes = self.road.lanes
        dtype = st.x.dtype
        probability = params.spawn_probability if probability is None else probability
        try_spawn = ~(d["u"] > probability)
        arm, dest = d["route"][0], d["route"][1]
        dest = (arm + 2) % 4 if go_straight else dest
        lane = jnp.asarray(self.arm_lane)[arm]
        s = longitudinal + 5.0 + d["z_position"] * position_deviation
        x, y = L.position(lanes, lane, s, jnp.zeros((), dtype))
        heading = L.heading_at(lanes, lane, s)
        speed = 8.0 + d["z_speed"] * speed_deviation
        dx, dy = st.x - x, st.y - y
        blocked = jnp.any(st.alive & (jnp.sqrt(dx * dx + dy * dy) < SPAWN_CLEARANCE))
        free = ~st.alive & ~jnp.asarray(self.is_controlled)
        pool_full = ~jnp.any(free)
        slot = jnp.argmax(free)
        spawned = try_spawn & ~blocked & ~pool_full
        lo, hi = params.idm.delta_range
        delta = lo + (hi - lo) * d["u_delta"]
        where = spawned & (jnp.arange(self.num_slots) == slot)
        st = self.put(st, where, x, y, heading, speed, speed, delta, arm, dest, params)
        skipped = try_spawn & ~blocked & pool_full
        st = st.replace(spawn_skipped=st.spawn_skipped + skipped)
        return st, dict(attempted=try_spawn, blocked=try_spawn & blocked, spawned=spawned, pool_full=skipped,
                        slot=jnp.where(spawned, slot, -1).astype(jnp.int32))

    def clear(self, st: IntersectionState):
        """``_clear_vehicles``: IDM vehicles leaving by an exit lane (``s >= length - 4 x 5`` m) are removed."""
        lanes = self.road.lanes
        s, _ = L.local_coordinates(lanes, st.lane, st.x, st.y)
        leaving = jnp.asarray(self.is_exit)[st.lane] & (s >= lanes.col("length")[st.lane] - 4 * L.VEHICLE_LENGTH)
        cleared = st.alive & leaving & ~jnp.asarray(self.is_controlled)
        return st.replace(alive=st.alive & ~cleared), cleared

    def place_agents(self, st: IntersectionState, z_ego, destination, params):
        """The controlled vehicles on their arms, then the removal of IDM vehicles closer than 20 m."""
        lanes = self.road.lanes
        dtype = st.x.dtype
        k = len(self.controlled)
        arms = np.arange(k) % 4
        lane = jnp.asarray(self.arm_lane[arms])
        s = 60.0 + 5.0 * (1.0 + z_ego)
        x, y = L.position(lanes, lane, s, jnp.zeros_like(s))
        heading = L.heading_at(lanes, lane, jnp.full_like(s, 60.0))
        speed = lanes.col("speed_limit")[lane]
        dest = jnp.where(params.destination >= 0, params.destination, destination)
        for i in range(k):  # appended one after the other
            where = jnp.arange(self.num_slots) == i
            st = self.put(st, where, x[i], y[i], heading[i], speed[i], speed[i], params.idm.delta, int(arms[i]),
                          dest[i].astype(jnp.int32), params)
        ts = jnp.asarray(params.target_speeds, dtype)
        index = jax.vmap(Veh.speed_to_index, in_axes=(0, None))(st.speed, ts)
        ctrl = jnp.asarray(self.is_controlled)
        st = st.replace(speed_index=jnp.where(ctrl, index, 0), target_speed=jnp.where(ctrl, ts[index], st.target_speed))
        dx, dy = st.x[:, None] - x[None, :], st.y[:, None] - y[None, :]
        close = jnp.any(jnp.sqrt(dx * dx + dy * dy) < EGO_CLEARANCE, axis=1)
        return st.replace(alive=st.alive & ~(close & ~ctrl))

    def default_params(self):
        raise NotImplementedError  # built by make_intersection from the config

    def outcome(self, prev, state, action, params: IntersectionTrafficParams):
        idx = np.asarray(self.controlled)
        lanes = self.road.lanes
        dtype = state.x.dtype
        crashed, on_road, lane = state.crashed[idx], state.on_road[idx], state.lane[idx]
        s, _ = L.local_coordinates(lanes, lane, state.x[idx], state.y[idx])
        arrived = jnp.asarray(self.is_exit)[lane] & (s >= EXIT_DISTANCE)
        lo, hi = params.reward_speed_range
        high_speed = jnp.clip(0 + (state.speed[idx] - lo) * (1 - 0) / (hi - lo), 0, 1)
        col, arr, onr = crashed.astype(dtype), arrived.astype(dtype), on_road.astype(dtype)
        reward = (0 + params.collision_reward * col + params.high_speed_reward * high_speed
                  + params.arrived_reward * arr + params.on_road_reward * onr)
        reward = jnp.where(arrived, params.arrived_reward, reward) * onr
        normalised = (0 + (reward - params.collision_reward) * (1 - 0)
                      / (params.arrived_reward - params.collision_reward))
        reward = jnp.where(params.normalize_reward, normalised, reward)
        cost = (params.collision_cost * crashed).astype(dtype)
        terminated = crashed | arrived | (params.offroad_terminal & ~on_road)
        env_terminated = jnp.any(crashed) | jnp.all(arrived) | (params.offroad_terminal & ~on_road[0])
        info = {"arrived": arrived, "env_terminated": env_terminated,
                "rewards": {"collision_reward": col, "high_speed_reward": high_speed, "arrived_reward": arr,
                            "on_road_reward": onr}}
        return reward.astype(dtype), cost, terminated, info


class IntersectionTrafficEnv(TrafficEnv):
    """:class:`TrafficEnv` with the regulated road, the spawns and the clears of the intersection."""

    action_names = ACTIONS  # DiscreteMetaAction(lateral=False): index -> meta-action

    def __init__(self, task: IntersectionTraffic, default_params):
        super().__init__(task, default_params)
        self.num_actions = len(ACTIONS)

    def _reset(self, key, params):
        key_init, key_obs = jax.random.split(key)
        return self.reset_from_draws(self.task.reset_draws(key_init, params), params, key_obs)

    def reset_from_draws(self, draws: dict, params, key=None, events: bool = False):
        """``_make_vehicles`` with the given draws (:meth:`IntersectionTraffic.reset_draws`): ``(obs, state)``,
        and with ``events`` the spawn events of the initial attempts and of the challenger."""
        task = self.task
        st = task.empty_state(params)
        n = task.initial_vehicle_count - 1
        grid = np.linspace(0, 80, task.initial_vehicle_count)[:max(n, 0)]

        def attempt(st, inp):
            d, longitudinal = inp
            st, ev = task.spawn(st, d, params, longitudinal=longitudinal, probability=0.6)
            return st, ev

        initial = None
        if n > 0:
            st, initial = jax.lax.scan(attempt, st, (draws["initial"], jnp.asarray(grid, st.x.dtype)))
        dt = 1.0 / self.simulation_frequency
        obstacles = self._obstacles(params, st.x.dtype)
        st, _ = self._frames(st, params, obstacles, dt, task.warmup_frames)
        first = jax.tree_util.tree_map(lambda a: a[0], draws["challenger"])
        st, challenger = task.spawn(st, first, params, longitudinal=60.0, position_deviation=0.1,
                                    speed_deviation=0.0, probability=1.0, go_straight=True)
        st = task.place_agents(st, draws["z_ego"], draws["destination"], params)
        if events:
            return self.observe(st, params, key), st, dict(initial=initial, challenger=challenger)
        return self.observe(st, params, key), st

    def _frame(self, st, circles, params, obstacles, dt):
        """``road.act()``, then ``RegulatedRoad.step(dt)``: the rules every ``period`` road steps, the kinematics."""
        st = drivers.road_act(self.road, st, self.is_idm, self.is_mdp, params.idm, obstacles, circles)
        steps = st.road_steps + 1
        due = steps % self.task.period == 0

        def rules(s):
            return regulation.enforce_road_rules(self.road, s, s.yielding, s.yield_timer, self.task.priority,
                                                 self.is_idm, s.order, self._predictions(s))

        # the rules run on one frame in `period`: under vmap only for the environments where they are due
        row = sparse_map(rules, due[None], jax.tree_util.tree_map(lambda a: a[None], st), fraction=RULES_FRACTION,
                         min_rows=8)
        ts, yl, yt = (a[0] for a in row)
        st = st.replace(target_speed=jnp.where(due, ts, st.target_speed), yielding=jnp.where(due, yl, st.yielding),
                        yield_timer=jnp.where(due, yt, st.yield_timer), road_steps=steps)
        return self._road_step(st, obstacles, dt)

    def _predictions(self, st):
        """The regulation's predicted trajectories (None: every slot along its route, as ``ControlledVehicle``)."""
        return None

    def _act(self, st, action, params):
        """The agents' actions on the first frame of a step: ``MDPVehicle.act`` of the meta-actions."""
        return self._decide(st, jnp.asarray(META_INDEX)[action], params)

    def _record(self, st):
        """The per-frame fields :meth:`step_substeps` returns."""
        return dict(x=st.x, y=st.y, heading=st.heading, speed=st.speed, crashed=st.crashed, lane=st.lane,
                    alive=st.alive, yielding=st.yielding, target_speed=st.target_speed)

    def _step(self, key, state, action, params, record):
        prev = state
        dt = 1.0 / self.simulation_frequency
        obstacles = self._obstacles(params, state.x.dtype)
        state = self._act(state, action, params)

        state, trajectory = self._frames(state, params, obstacles, dt, self.frames, self._record if record else None)
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
        # after the step's outcome: _clear_vehicles, then _spawn_vehicle
        state, cleared = self.task.clear(state)
        draws = self.task.spawn_draws(jax.random.fold_in(key, 1), 1, state.x.dtype)
        state, ev = self.task.spawn(state, jax.tree_util.tree_map(lambda a: a[0], draws), params)
        info.update(cleared=cleared, spawn_draws=jax.tree_util.tree_map(lambda a: a[0], draws), spawn=ev,
                    pool_full=ev["pool_full"], spawn_skipped=state.spawn_skipped,
                    vehicles=jnp.sum(state.alive).astype(jnp.int32))
        return obs, state, reward, cost, done, info, trajectory

    def _list_order(self, state):
        """Slots sorted by their position in highway-env's ``road.vehicles`` (empty slots last)."""
        return jnp.argsort(jnp.where(state.alive, state.order, jnp.iinfo(jnp.int32).max), stable=True)

    def _collide(self, st, x, y, h, v, alive, crashed, obstacles, dt):
        """The collision loop in list order (a vehicle's impact is that of its last colliding pair in the loop)."""
        perm = self._list_order(st)
        inv = jnp.argsort(perm)
        impact, has_impact, crashed = pair_collisions.collide(x[perm], y[perm], h[perm], v[perm], alive[perm],
                                                              crashed[perm], self.check_collisions, obstacles, dt)
        return impact[inv], has_impact[inv], crashed[inv]

    def observe(self, state, params, key=None):
        """The observations with the vehicles in highway-env's list order (it breaks distance ties)."""
        n = self.num_slots
        perm = self._list_order(state)
        listed = jax.tree_util.tree_map(lambda a: a[perm] if (a.ndim >= 1 and a.shape[0] == n) else a, state)
        observers = jnp.argsort(perm)[jnp.asarray(self.controlled)]
        table = kinematic_obs.feature_table(self.road, listed, None)
        key = jax.random.key(0) if key is None else key
        keys = jax.random.split(key, self.num_agents)
        obs = jax.vmap(lambda o, k: kinematic_obs.observe_one(self.obs_config, self.road, listed, table, o, None, k))(
            observers, keys)
        missing = self.obs_config.vehicles_count - obs.shape[1]  # a pool smaller than the observed count
        if missing > 0:
            obs = jnp.concatenate([obs, jnp.zeros((obs.shape[0], missing, obs.shape[2]), obs.dtype)], axis=1)
        return obs

    def check_action(self, action):
        """Integers of shape ``[K]`` in ``0..2`` (SLOWER, IDLE, FASTER)."""
        concrete = not isinstance(action, jax.core.Tracer)
        arr = np.asarray(action) if concrete else action
        if tuple(np.shape(arr)) != self.action_shape:
            raise ValueError(f"{self.name}: action must have shape {self.action_shape} (one meta-action per "
                             f"controlled vehicle), got {tuple(np.shape(arr))}")
        if not jnp.issubdtype(arr.dtype, jnp.integer):
            raise ValueError(f"{self.name}: discrete actions must be integers in 0..2 {ACTIONS}, got dtype {arr.dtype}")
        if concrete and (np.any(arr < 0) or np.any(arr > 2)):
            raise ValueError(f"{self.name}: discrete actions must be in 0..2 {ACTIONS}, got {arr.tolist()}")
        return jnp.clip(jnp.asarray(action), 0, 2).astype(jnp.int32)


# ----------------------------------------------------------------------------------------------
# Configuration: highway-env's config dict and keyword overrides -> an IntersectionTrafficEnv

def _action(name, value):
    action = unwrap_section(name, "action", value, "MultiAgentAction", "action_config")
    kind = action.pop("type", None)
    if kind != "DiscreteMetaAction":
        raise ValueError(f"{name}: action type must be 'DiscreteMetaAction' (or MultiAgentAction of it), got {kind!r}")
    if action.pop("longitudinal", True) is not True or action.pop("lateral", False) is not False:
        raise ValueError(f"{name}: only DiscreteMetaAction(longitudinal=True, lateral=False) is supported "
                         f"(actions {ACTIONS})")
    ts = np.asarray(action.pop("target_speeds", TARGET_SPEEDS), dtype=np.float64)
    if ts.ndim != 1 or ts.size < 2 or not np.all(np.diff(ts) > 0) or not np.all(np.isfinite(ts)):
        raise ValueError(f"{name}: target_speeds must be an increasing list of at least 2 finite speeds, "
                         f"got {ts.tolist()}")
    if action:
        raise ValueError(f"{name}: DiscreteMetaAction keys {sorted(action)} are not understood; allowed: "
                         f"['type', 'longitudinal', 'lateral', 'target_speeds']")
    return ts


def default_num_slots(controlled: int, initial_vehicle_count: int, duration: float, policy_frequency: int) -> int:
    """Slots no default episode can fill: the agents, the initial vehicles and challenger, one spawn per step."""
    return controlled + initial_vehicle_count + int(step_limit(duration, policy_frequency))


def intersection_settings(name: str, cfg: dict) -> tuple[dict, dict]:
    """The checked values of an intersection config ``cfg`` (defaults merged with what was given), except
    the action: ``(task keywords, params keywords)`` for :class:`IntersectionTraffic` and its params."""
    sim = int_value(name, "simulation_frequency", cfg["simulation_frequency"], 2)
    pol = int_value(name, "policy_frequency", cfg["policy_frequency"], 1, sim)
    k = int_value(name, "controlled_vehicles", cfg["controlled_vehicles"], 1)
    n_init = int_value(name, "initial_vehicle_count", cfg["initial_vehicle_count"], 1)
    duration = number_value(name, "duration", cfg["duration"], positive=True)
    num_slots = cfg.get("num_slots", default_num_slots(k, n_init, duration, pol))
    num_slots = int_value(name, "num_slots", num_slots, k + 1)
    dest = cfg["destination"]
    if dest is None:
        destination = -1
    elif isinstance(dest, str) and dest in ("o0", "o1", "o2", "o3"):
        destination = int(dest[1])
    else:
        raise ValueError(f"{name}: destination must be one of 'o0'..'o3' or None (random exit), got {dest!r}")
    p = number_value(name, "spawn_probability", cfg["spawn_probability"])
    if not 0 <= p <= 1:
        raise ValueError(f"{name}: spawn_probability must be in [0, 1], got {p!r}")
    obs_cfg = observation_config(name, cfg["observation"])
    rsr = speed_range(name, cfg["reward_speed_range"])
    for key in ("normalize_reward", "offroad_terminal"):
        flag_value(name, key, cfg[key])
    idm = idm_params(name, cfg.get("idm"), intersection_idm())
    task = dict(controlled_vehicles=k, initial_vehicle_count=n_init, num_slots=num_slots, simulation_frequency=sim,
                policy_frequency=pol, obs_config=obs_cfg)
    params = dict(
        duration=duration, collision_cost=cost_value(name, "collision_cost", cfg.get("collision_cost", 5.0)),
        idm=idm, obstacles=None, spawn_probability=p, destination=destination,
        collision_reward=number_value(name, "collision_reward", cfg["collision_reward"]),
        high_speed_reward=number_value(name, "high_speed_reward", cfg["high_speed_reward"]),
        arrived_reward=number_value(name, "arrived_reward", cfg["arrived_reward"]),
        on_road_reward=number_value(name, "on_road_reward", cfg.get("on_road_reward", 0.0)),
        reward_speed_range=(float(rsr[0]), float(rsr[1])),
        normalize_reward=bool(cfg["normalize_reward"]), offroad_terminal=bool(cfg["offroad_terminal"]))
    if params["normalize_reward"] and params["arrived_reward"] == params["collision_reward"]:
        raise ValueError(f"{name}: normalize_reward needs arrived_reward != collision_reward")
    return task, params


def make_intersection(name: str, env_config: dict | None = None, **overrides) -> IntersectionTrafficEnv:
    """``intersection-v0`` / ``intersection-multi-agent-v0`` from highway-env's config keys.

    Keywords are highway-env config keys (``controlled_vehicles``, ``duration``, ``destination``,
    ``initial_vehicle_count``, ``spawn_probability``, the reward keys, ``observation``, ``action``, ...)
    plus ``num_slots`` (the vehicle pool; default :func:`default_num_slots`), ``collision_cost`` and
    ``idm`` (an :class:`~envs_jax.idm.IDMParams` or a dict of its fields; default the env's drivers).
    Unknown keys or bad values raise ``ValueError`` naming them and what is allowed.
    """
    cfg = dict(DEFAULTS[name])
    cfg["observation"] = dict(OBSERVATION)
    cfg["action"] = {"type": "DiscreteMetaAction", "longitudinal": True, "lateral": False,
                     "target_speeds": list(TARGET_SPEEDS)}
    cfg.update(config_given(name, cfg, OWN_KEYS, env_config, overrides, "allowed: False"))
    task, params = intersection_settings(name, cfg)
    ts = _action(name, cfg["action"])
    return IntersectionTrafficEnv(IntersectionTraffic(name, **task), IntersectionTrafficParams(target_speeds=ts,
                                                                                               **params))
