"""``roundabout-v0`` (highway-env ``envs/roundabout_env.py``) with IDM traffic and K controlled vehicles.

Road: ``RoundaboutEnv._make_road`` (:func:`envs_jax.scenarios.roundabout.build_road`): a
two-lane ring of radii 20 and 24 m with four single-lane sine access and exit roads.
Vehicles, in list order: the K controlled vehicles (agent order), then highway-env's
traffic, every one made with ``make_on_lane`` (position and heading of the lane at its
longitudinal coordinate), routed with ``plan_route_to`` to a destination drawn from
``exr, sxr, nxr`` (the incoming vehicle's fixed by ``incoming_vehicle_destination``) and
``randomize_behavior``: the incoming vehicle on we->sx lane 1 at 5 m, two on we->sx lane 0
at 20 and -20 m and the entering one on eer->ees at 50 m, each position + 2 N(0, 1) m and
speed 16 + 2 N(0, 1) m/s. No spawning.

Controlled vehicles (highway-env places one; agent 0 is it, on ser->ses at 125 m, 8 m/s,
routed to the north exit ``nxs``): agent k enters from the south, west, north, east
access road for k mod 4 = 0, 1, 2, 3, at 125 m (k < 4) or 100 m (k >= 4) along it, at 8
m/s, routed (``plan_route_to``) across the ring to the opposite exit (``nxs, exs, sxs,
wxs``), as highway-env's ego crosses from south to north. K is 1 to 8.

Reward of agent k (highway-env's ``_reward`` with vehicle k as the ego and agent k's own
action): collision (crashed), high speed (speed index / 2: highway-env divides by the size
of ``MDPVehicle.DEFAULT_TARGET_SPEEDS``, 3, less one), lane change (LANE_LEFT or
LANE_RIGHT) and on-road terms, normalised from ``[collision, high_speed]`` to [0, 1] with
``normalize_reward``, times on-road. Cost ``collision_cost * crashed``. Agent k terminates
when crashed; the episode is truncated at ``duration`` (11 s).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import kinematic_obs
from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from envs_jax import vehicle as Veh
from envs_jax.scenarios import config_values as CV
from envs_jax.scenarios.roundabout import build_road
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams

NAME = "roundabout-v0"
AGENT_SPEED = 8.0
ENTRIES = ((("ser", "ses", 0), "nxs"), (("wer", "wes", 0), "exs"), (("ner", "nes", 0), "sxs"),
           (("eer", "ees", 0), "wxs"))
AGENT_LONGITUDINAL = (125.0, 100.0)
MAX_AGENTS = len(ENTRIES) * len(AGENT_LONGITUDINAL)
DESTINATIONS = ("exr", "sxr", "nxr")
# highway-env's traffic: (lane, longitudinal, speed) before the noise, list order
TRAFFIC = ((("we", "sx", 1), 5.0, 16.0), (("we", "sx", 0), 20.0, 16.0), (("we", "sx", 0), -20.0, 16.0),
           (("eer", "ees", 0), 50.0, 16.0))
NUM_TRAFFIC = len(TRAFFIC)
POSITION_DEVIATION = 2.0
SPEED_DEVIATION = 2.0
SPEED_INDEX_DENOMINATOR = 2.0  # MDPVehicle.DEFAULT_TARGET_SPEEDS.size - 1


def agent_start(k: int):
    """``(lane, longitudinal, destination)`` of agent k."""
    lane, destination = ENTRIES[k % len(ENTRIES)]
    return lane, AGENT_LONGITUDINAL[k // len(ENTRIES)], destination


@struct.dataclass
class RoundaboutTaskParams(TrafficParams):
    incoming_vehicle_destination: int = -1  # -1: random (highway-env's None), else an index into DESTINATIONS
    collision_reward: float = -1.0
    high_speed_reward: float = 0.2
    right_lane_reward: float = 0.0  # listed by highway-env, not a term of its reward
    lane_change_reward: float = -0.05
    on_road_reward: float = 0.0  # highway-env's config.get("on_road_reward", 0)
    normalize_reward: bool = True


DEFAULTS = dict(simulation_frequency=15, policy_frequency=1, controlled_vehicles=1, incoming_vehicle_destination=None,
                collision_reward=-1, high_speed_reward=0.2, right_lane_reward=0, lane_change_reward=-0.05,
                duration=11, normalize_reward=True)
DEFAULT_OBSERVATION = {"type": "Kinematics", "absolute": True,
                       "features_range": {"x": [-100, 100], "y": [-100, 100], "vx": [-15, 15], "vy": [-15, 15]}}
DEFAULT_ACTION = {"type": "DiscreteMetaAction", "target_speeds": [0, 8, 16]}
OWN_KEYS = ("num_slots", "collision_cost", "idm", "on_road_reward")


def shortest_path(graph: dict, start: str, goal: str) -> list:
    """``RoadNetwork.shortest_path``: the first path of its breadth-first search (successors sorted)."""
    queue = [(start, [start])]
    while queue:
        node, path = queue.pop(0)
        if node not in graph:
            return []
        for nxt in sorted(k for k in graph[node] if k not in path):
            if nxt == goal:
                return path + [nxt]
            if nxt in graph:
                queue.append((nxt, path + [nxt]))
    return []


def route_table(road, destinations) -> tuple:
    """``plan_route_to`` from every lane of ``road`` to every node of ``destinations``.

    Returns ``(roads, ids, lens)``: ``[lanes, destinations, R]`` road indices and lane ids
    (the first step keeps the lane's id, as ``plan_route_to``) and ``[lanes, destinations]``
    lengths; a destination not reachable from a lane gives the lane's own road only.
    """
    graph = {}
    for f, t in road.roads:
        graph.setdefault(f, {})[t] = True
    routes = []
    for f, t, _ in road.lane_names:
        row = []
        for dest in destinations:
            path = shortest_path(graph, t, dest)
            row.append([f] + path if path else [f, t])
        routes.append(row)
    length = max(len(nodes) - 1 for row in routes for nodes in row)
    shape = (len(routes), len(destinations))
    roads = np.zeros(shape + (length,), np.int32)
    ids = np.zeros(shape + (length,), np.int32)
    lens = np.zeros(shape, np.int32)
    for g, row in enumerate(routes):
        for d, nodes in enumerate(row):
            roads[g, d], ids[g, d], lens[g, d] = road.route(nodes, first_lane_id=int(road.lane_id[g]), length=length)
    return roads, ids, lens


class RoundaboutTask(Task):
    """roundabout-v0 with ``controlled_vehicles`` agents in ``num_slots`` slots."""

    def __init__(self, controlled_vehicles: int, num_slots: int, simulation_frequency: int,
                 policy_frequency: int, obs_config: kinematic_obs.KinematicsConfig):
        self.name = NAME
        self.road = build_road()
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.obs_config = obs_config
        self.num_agents = controlled_vehicles
        self.num_vehicles = controlled_vehicles + NUM_TRAFFIC
        self.num_slots = num_slots
        self.controlled = tuple(range(controlled_vehicles))
        # every agent starts on a one-lane access road: highway-env's default y range is fixed there
        self.obs_range_lanes = (1,) * controlled_vehicles
        starts = [agent_start(k) for k in range(controlled_vehicles)]
        self.destinations = DESTINATIONS + tuple(sorted({d for _, _, d in starts}))
        self._build_routes()
        self.agent_lanes = np.array([self.road.lane(*lane) for lane, _, _ in starts], np.int32)
        self.agent_s = np.array([s for _, s, _ in starts])
        self.agent_dest = np.array([self.destinations.index(d) for _, _, d in starts], np.int32)
        self.traffic_lanes = np.array([self.road.lane(*lane) for lane, _, _ in TRAFFIC], np.int32)

    def _build_routes(self):
        """``plan_route_to`` from every lane to every destination: ``[lanes, destinations, R]`` tables."""
        self.route_roads, self.route_ids, self.route_lens = route_table(self.road, self.destinations)
        self.route_length = self.route_roads.shape[-1]

    def default_params(self) -> RoundaboutTaskParams:
        raise NotImplementedError  # built by make_roundabout from the config

    def initial_vehicles(self, key, params: RoundaboutTaskParams):
        """``_make_vehicles`` with the draws from ``key``."""
        return self.place(self.draws(key, params), params)

    def draws(self, key, params: RoundaboutTaskParams) -> dict:
        """The random numbers of ``_make_vehicles`` for the four IDM vehicles, list order: ``position`` and
        ``speed`` (standard normal), ``destination`` (index into ``exr, sxr, nxr``; the incoming vehicle's
        is ``incoming_vehicle_destination`` when set) and ``delta`` (``randomize_behavior``)."""
        dtype = L.float_dtype()
        k_pos, k_speed, k_dest, k_delta = jax.random.split(key, 4)
        n = NUM_TRAFFIC
        dest = jax.random.randint(k_dest, (n,), 0, len(DESTINATIONS))
        fixed = params.incoming_vehicle_destination
        dest = dest.at[0].set(jnp.where(fixed >= 0, fixed, dest[0]))
        lo, hi = params.idm.delta_range
        return dict(position=jax.random.normal(k_pos, (n,), dtype), speed=jax.random.normal(k_speed, (n,), dtype),
                    destination=dest, delta=jax.random.uniform(k_delta, (n,), dtype, lo, hi))

    def place(self, draws: dict, params: RoundaboutTaskParams) -> dict:
        """Per-slot initial values and routes from the draws (``make_on_lane``, ``plan_route_to``)."""
        dtype = L.float_dtype()
        base = np.array([[s, v] for _, s, v in TRAFFIC])
        s_t = jnp.asarray(base[:, 0], dtype) + jnp.asarray(draws["position"], dtype) * POSITION_DEVIATION
        v_t = jnp.asarray(base[:, 1], dtype) + jnp.asarray(draws["speed"], dtype) * SPEED_DEVIATION
        lanes = jnp.asarray(np.concatenate([self.agent_lanes, self.traffic_lanes]))
        s = jnp.concatenate([jnp.asarray(self.agent_s, dtype), s_t])
        x, y = L.position(self.road.lanes, lanes, s, jnp.zeros_like(s))
        heading = L.heading_at(self.road.lanes, lanes, s)
        speed = jnp.concatenate([jnp.full(self.num_agents, AGENT_SPEED, dtype), v_t])
        delta = jnp.concatenate([jnp.full(self.num_agents, params.idm.delta, dtype),
                                 jnp.asarray(draws["delta"], dtype)])
        dest = jnp.concatenate([jnp.asarray(self.agent_dest), jnp.asarray(draws["destination"], jnp.int32)])
        # plan_route_to starts from the closest lane of the new vehicle, not the lane it was made on
        start = LL.locate(self.road.lanes, x, y, heading)[0]
        roads = jnp.asarray(self.route_roads)[start, dest]
        ids = jnp.asarray(self.route_ids)[start, dest]
        lens = jnp.asarray(self.route_lens)[start, dest]
        pad = self.num_slots - self.num_vehicles
        fill = lambda a, val: jnp.concatenate([a, jnp.full((pad,) + a.shape[1:], val, a.dtype)])
        return dict(x=fill(x, 0.0), y=fill(y, 0.0), heading=fill(heading, 0.0), speed=fill(speed, 0.0),
                    alive=jnp.arange(self.num_slots) < self.num_vehicles, delta=fill(delta, params.idm.delta),
                    routes=(fill(roads, -1), fill(ids, -1), fill(lens, 0)))

    def outcome(self, prev, state, action, params: RoundaboutTaskParams):
        idx = np.asarray(self.controlled)
        dtype = state.x.dtype
        crashed = state.crashed[idx]
        col = crashed.astype(dtype)
        high_speed = state.speed_index[idx].astype(dtype) / SPEED_INDEX_DENOMINATOR
        lane_change = ((action == Veh.LANE_LEFT) | (action == Veh.LANE_RIGHT)).astype(dtype)
        onr = state.on_road[idx].astype(dtype)
        reward = (params.collision_reward * col + params.high_speed_reward * high_speed
                  + params.lane_change_reward * lane_change + params.on_road_reward * onr)
        lo, hi = params.collision_reward, params.high_speed_reward
        normalised = 0 + (reward - lo) * (1 - 0) / (hi - lo)
        reward = jnp.where(params.normalize_reward, normalised, reward) * onr
        cost = (params.collision_cost * crashed).astype(dtype)
        info = {"rewards": {"collision_reward": col, "high_speed_reward": high_speed,
                            "lane_change_reward": lane_change, "on_road_reward": onr}}
        return reward.astype(dtype), cost, crashed, info


def make_roundabout(name: str = NAME, env_config: dict | None = None, **overrides) -> TrafficEnv:
    """``roundabout-v0`` from highway-env's config keys (``env_config`` and/or keywords).

    Keys: highway-env's ``RoundaboutEnv`` config (``controlled_vehicles`` 1..8,
    ``incoming_vehicle_destination`` None or 0..2, the reward keys, ``duration``,
    ``normalize_reward``, ``observation``, ``action``, frequencies; rendering keys are ignored)
    plus ``num_slots`` (>= controlled_vehicles + 4), ``collision_cost``, ``on_road_reward`` and
    ``idm`` (an IDMParams or a dict of its fields). Unknown or non-applicable keys and bad values
    raise ``ValueError`` naming them and what is allowed.
    """
    cfg = dict(DEFAULTS)
    cfg["observation"] = DEFAULT_OBSERVATION
    cfg["action"] = DEFAULT_ACTION
    cfg.update(CV.config_given(name, cfg, OWN_KEYS, env_config, overrides, "roundabout-v1 is not implemented"))

    sim = CV.int_value(name, "simulation_frequency", cfg["simulation_frequency"], 1)
    pol = CV.int_value(name, "policy_frequency", cfg["policy_frequency"], 1, sim)
    k = CV.int_value(name, "controlled_vehicles", cfg["controlled_vehicles"], 1, MAX_AGENTS)
    total = k + NUM_TRAFFIC
    num_slots = CV.int_value(name, "num_slots", cfg.get("num_slots", total), total)
    incoming = cfg["incoming_vehicle_destination"]
    if incoming is not None:
        incoming = CV.int_value(name, "incoming_vehicle_destination", incoming, 0, len(DESTINATIONS) - 1)
    obs_cfg = CV.observation_config(name, cfg["observation"])
    action = CV.meta_action_config(name, cfg["action"])
    CV.flag_value(name, "normalize_reward", cfg["normalize_reward"])
    task = RoundaboutTask(k, num_slots, sim, pol, obs_cfg)
    num = lambda key: CV.number_value(name, key, cfg[key])
    params = RoundaboutTaskParams(
        duration=CV.number_value(name, "duration", cfg["duration"], positive=True),
        collision_cost=CV.cost_value(name, "collision_cost", cfg.get("collision_cost", 5.0)),
        target_speeds=action.get("target_speeds", np.linspace(20, 30, 3)),
        idm=CV.idm_params(name, cfg.get("idm")), obstacles=None,
        incoming_vehicle_destination=-1 if incoming is None else incoming,
        collision_reward=num("collision_reward"), high_speed_reward=num("high_speed_reward"),
        right_lane_reward=num("right_lane_reward"), lane_change_reward=num("lane_change_reward"),
        on_road_reward=CV.number_value(name, "on_road_reward", cfg.get("on_road_reward", 0.0)),
        normalize_reward=bool(cfg["normalize_reward"]),
    )
    if params.normalize_reward and params.high_speed_reward == params.collision_reward:
        raise ValueError(f"{name}: normalize_reward needs high_speed_reward != collision_reward")
    return TrafficEnv(task, params)
