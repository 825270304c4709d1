"""The authors' roundabout with K controlled agents, on the traffic core (docs/scenarios.md).

``envs_jax.make("roundabout-k", controlled_vehicles=K, other_vehicles=N)``, K in 2..8, N in 0..8.

Road, dynamics and actions are those of the two-agent ``roundabout``
(:mod:`envs_jax.scenarios.roundabout`): the two-lane ring with four sine access and exit
roads, MDP meta-actions over target speeds [0, 4, 8, 12, 16], 15 frames per decision,
20 s episodes.

Placement: the two-agent scenario is symmetric under a half turn about the ring's centre,
which swaps the west and east, and the south and north, roads. Agents 0 and 1 start as
there (west entry at (-45, 2), south entry at (2, 85)); agents 2 and 3 are agents 0 and 1
turned by the half turn (east entry at (45, -2), north entry at (-2, -85)), position,
heading, route and exit alike; agent k >= 4 starts 20 m behind agent k - 4 on the same
access road, with its route. So agents entering from the west or the south leave by the
north exit (three quarters and half of the ring), those entering from the east or the
north by the south exit. All start at 8 m/s, headings along their access roads.
Vehicles (slots, the order of highway-env's ``road.vehicles``, which orders the
collision checks): agent 1, agent 0 (the two-agent ``[follower, leader]``), agents 2 to
K - 1, then the traffic.

Traffic (``other_vehicles = N``): IDM/MOBIL drivers at highway-env's roundabout-v0
positions without its noise (ring lane we->sx: lane 1 at 5 m, lane 0 at 20 m and -20 m;
the east access road at 50 m), then the same four turned by the half turn, the first N
of these eight, each at 16 m/s with ``idm.delta`` as exponent, routed (``plan_route_to``
from its closest lane) to the exit road ``exr, sxr, nxr, wxr`` for j = 0..3 and to the
half-turned exit of vehicle j - 4 for j >= 4. Nothing is random: every reset gives the
same state.

Observation ``[K, 4 * vehicles_count]`` (default ``vehicles_count = K``): the authors'
absolute, unnormalised ``[x, y, vx, vy]`` rows, agent k's own first, then the nearest
other vehicles, agents or traffic, nearest first, ties in agent order
(:mod:`envs_jax.nearest_view`); with K = 2 and no traffic, the two-agent ``[2, 8]`` view.

Reward and cost per agent, the two-agent terms: ``collision_reward`` (-5) on every step
while crashed, ``speed_reward`` (2) while 10 <= speed <= 15 m/s, ``arrival_reward`` (5)
on every step while arrived, i.e. on its exit lane (nxs->nxr or sxs->sxr) at s >=
``arrival_s`` (20 m); cost ``collision_cost * crashed``. There is no ranking: the
arrival bonus is paid per step to each agent on its exit, whatever the others did (the
authors' roundabout pays no first-arrival bonus, unlike their merge and intersection).
Agent k terminates while crashed or arrived; the episode ends when every agent has
terminated or at the time limit.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from envs_jax import nearest_view
from envs_jax.scenarios import config_values as CV
from envs_jax.scenarios.roundabout import FOLLOWER_ROUTE, LEADER_ROUTE, build_road
from envs_jax.scenarios.roundabout_traffic import route_table
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams

NAME = "roundabout-k"
MIN_AGENTS, MAX_AGENTS = 2, 8
AGENT_SPEED = 8.0
TRAFFIC_SPEED = 16.0
HALF_PI = np.pi / 2
# (x, y, heading) of agent k: 0, 1 as the two-agent scenario; 2, 3 their half turns; k >= 4 20 m behind k - 4
AGENT_POSES = ((-45.0, 2.0, 0.0), (2.0, 85.0, -HALF_PI), (45.0, -2.0, np.pi), (-2.0, -85.0, HALF_PI),
               (-65.0, 2.0, 0.0), (2.0, 105.0, -HALF_PI), (65.0, -2.0, np.pi), (-2.0, -105.0, HALF_PI))
_TURN = {"w": "e", "e": "w", "s": "n", "n": "s"}


def half_turn(node: str) -> str:
    """The node a half turn about the centre maps ``node`` to (its first letter is its compass side)."""
    return _TURN[node[0]] + node[1:]


ROUTES = (LEADER_ROUTE, FOLLOWER_ROUTE, [half_turn(n) for n in LEADER_ROUTE],
          [half_turn(n) for n in FOLLOWER_ROUTE])
GOALS = (("nxs", "nxr", 0), ("nxs", "nxr", 0), ("sxs", "sxr", 0), ("sxs", "sxr", 0))
# highway-env's roundabout-v0 traffic without its noise: (lane, longitudinal); then their half turns
_TRAFFIC_V0 = ((("we", "sx", 1), 5.0), (("we", "sx", 0), 20.0), (("we", "sx", 0), -20.0), (("eer", "ees", 0), 50.0))
TRAFFIC = _TRAFFIC_V0 + tuple(((half_turn(f), half_turn(t), i), s) for (f, t, i), s in _TRAFFIC_V0)
EXITS = ("exr", "sxr", "nxr", "wxr")
TRAFFIC_EXITS = EXITS + tuple(half_turn(e) for e in EXITS)
MAX_TRAFFIC = len(TRAFFIC)


def slot_order(k: int) -> tuple:
    """``controlled``: the slot of agent 0..k-1 (slots hold agent 1, agent 0, agents 2..k-1, then the traffic)."""
    return (1, 0) + tuple(range(2, k))


@struct.dataclass
class RoundaboutAgentsParams(TrafficParams):
    collision_reward: float = -5.0  # per step while crashed
    speed_reward: float = 2.0  # while speed_band_low <= speed <= speed_band_high
    speed_band_low: float = 10.0
    speed_band_high: float = 15.0
    arrival_reward: float = 5.0  # every step while arrived
    arrival_s: float = 20.0  # arrived: on the agent's exit lane with s >= arrival_s


class RoundaboutAgentsTask(Task):
    """The authors' roundabout with ``k`` agents and ``n`` IDM vehicles (module docstring)."""

    simulation_frequency = 15
    policy_frequency = 1

    def __init__(self, k: int, n: int, vehicles_count: int, simulation_frequency: int = 15,
                 policy_frequency: int = 1):
        self.name = NAME
        self.road = build_road()
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.num_agents, self.num_traffic = k, n
        self.num_slots = k + n
        self.controlled = slot_order(k)
        self.vehicles_count = vehicles_count
        # the view lists the agents first (agent order), then the traffic slots
        self.view_order = self.controlled + tuple(range(k, k + n))
        road = self.road
        self.goal_lanes = np.array([road.lane(*GOALS[a % 4]) for a in range(k)], np.int32)
        self.traffic_lanes = np.array([road.lane(*lane) for lane, _ in TRAFFIC[:n]], np.int32)
        self.traffic_s = np.array([s for _, s in TRAFFIC[:n]])
        self.traffic_dest = np.array([TRAFFIC_EXITS.index(e) for e in TRAFFIC_EXITS[:n]], np.int32)
        tables = route_table(road, TRAFFIC_EXITS) if n else None
        self.route_length = max([len(LEADER_ROUTE) - 1] + ([tables[0].shape[-1]] if n else []))
        agent_routes = [road.route(ROUTES[a % 4], first_lane_id=0, length=self.route_length) for a in range(k)]
        by_slot = [agent_routes[self.controlled.index(s)] for s in range(k)]
        self.agent_routes = tuple(np.stack([r[i] for r in by_slot]) for i in range(3))
        if n:
            pad = self.route_length - tables[0].shape[-1]
            grow = lambda a, v: np.concatenate([a, np.full(a.shape[:-1] + (pad,), v, a.dtype)], axis=-1)
            self.route_tables = (grow(tables[0], -1), grow(tables[1], -1), tables[2])

    def default_params(self) -> RoundaboutAgentsParams:
        return RoundaboutAgentsParams(duration=20.0, collision_cost=5.0,
                                      target_speeds=np.array([0.0, 4.0, 8.0, 12.0, 16.0]))

    def initial_vehicles(self, key, params: RoundaboutAgentsParams) -> dict:
        """The deterministic placement of the module docstring (``key`` is not used)."""
        dtype = L.float_dtype()
        k, n = self.num_agents, self.num_traffic
        poses = np.array([AGENT_POSES[self.controlled[s]] for s in range(k)])  # slot order
        x, y, h = (jnp.asarray(poses[:, i], dtype) for i in range(3))
        speed = jnp.full(k, AGENT_SPEED, dtype)
        roads, ids, lens = (jnp.asarray(a) for a in self.agent_routes)
        if n:
            lanes = jnp.asarray(self.traffic_lanes)
            s = jnp.asarray(self.traffic_s, dtype)
            tx, ty = L.position(self.road.lanes, lanes, s, jnp.zeros_like(s))
            th = L.heading_at(self.road.lanes, lanes, s)
            # plan_route_to starts from the closest lane of the new vehicle, not the lane it was made on
            start = LL.locate(self.road.lanes, tx, ty, th)[0]
            dest = jnp.asarray(self.traffic_dest)
            cat = lambda a, b: jnp.concatenate([a, b.astype(a.dtype)])
            x, y, h = cat(x, tx), cat(y, ty), cat(h, th)
            speed = cat(speed, jnp.full(n, TRAFFIC_SPEED, dtype))
            roads, ids, lens = (cat(a, jnp.asarray(t)[start, dest]) for a, t in zip((roads, ids, lens),
                                                                                      self.route_tables))
        return dict(x=x, y=y, heading=h, speed=speed, alive=jnp.ones(k + n, bool),
                    delta=jnp.full(k + n, params.idm.delta, dtype), routes=(roads, ids, lens))

    def agent_lanes(self, state):
        """``(lane[K], s[K])``: each agent's closest lane and its longitudinal coordinate there."""
        idx = np.asarray(self.controlled)
        lane, s, _, _ = LL.locate(self.road.lanes, state.x[idx], state.y[idx], state.heading[idx])
        return lane, s

    def outcome(self, prev, state, action, params: RoundaboutAgentsParams):
        idx = np.asarray(self.controlled)
        dtype = state.x.dtype
        crashed = state.crashed[idx]
        speed = state.speed[idx]
        lane, s = self.agent_lanes(state)
        arrived = (lane == jnp.asarray(self.goal_lanes)) & (s >= params.arrival_s)
        in_band = (speed >= params.speed_band_low) & (speed <= params.speed_band_high)
        reward = (params.collision_reward * crashed + params.speed_reward * in_band
                  + params.arrival_reward * arrived).astype(dtype)
        cost = (params.collision_cost * crashed).astype(dtype)
        info = {"crash": jnp.any(crashed), "arrived": arrived}
        return reward, cost, crashed | arrived, info


class RoundaboutAgentsEnv(nearest_view.NearestViewEnv, TrafficEnv):
    """:class:`TrafficEnv` with the authors' observation (:mod:`envs_jax.nearest_view`)."""

    def __init__(self, task: RoundaboutAgentsTask, default_params: RoundaboutAgentsParams):
        super().__init__(task, default_params)
        self.use_nearest_view()


PARAM_KEYS = ("duration", "collision_cost", "collision_reward", "speed_reward", "speed_band_low", "speed_band_high",
              "arrival_reward", "arrival_s")
# the factory's own keywords besides PARAM_KEYS
FACTORY_KEYS = ("controlled_vehicles", "other_vehicles", "vehicles_count", "simulation_frequency", "policy_frequency",
                "target_speeds", "idm")


def make_roundabout_agents(name: str = NAME, env_config: dict | None = None, *, controlled_vehicles: int = 2,
                           other_vehicles: int = 0, vehicles_count: int | None = None,
                           simulation_frequency: int = 15, policy_frequency: int = 1, target_speeds=None,
                           idm=None, **values) -> RoundaboutAgentsEnv:
    """The authors' roundabout with ``controlled_vehicles`` agents (2..8) and ``other_vehicles`` IDM vehicles
    (0..8); ``vehicles_count`` rows per observation (2..K + N, default K); the reward, cost and duration
    numbers of :class:`RoundaboutAgentsParams` as keywords, ``target_speeds`` (an increasing list) and ``idm``
    (an IDMParams or a dict of its fields). Bad values raise ``ValueError`` naming the key and what is allowed."""
    CV.keywords_only(name, env_config, values, PARAM_KEYS, FACTORY_KEYS)
    k, n, count, sim, pol = CV.agents_layout(name, controlled_vehicles, other_vehicles, vehicles_count,
                                             simulation_frequency, policy_frequency, MIN_AGENTS, MAX_AGENTS,
                                             MAX_TRAFFIC)
    task = RoundaboutAgentsTask(k, n, count, sim, pol)
    params = task.default_params()
    fields = {key: CV.number_value(name, key, v, positive=key == "duration") for key, v in values.items()}
    for key in ("collision_cost", "speed_band_low", "speed_band_high", "arrival_s"):
        if key in fields and fields[key] < 0:
            raise ValueError(f"{name}: {key} must be >= 0, got {fields[key]!r}")
    lo, hi = (fields.get(key, getattr(params, key)) for key in ("speed_band_low", "speed_band_high"))
    if lo > hi:
        raise ValueError(f"{name}: speed_band_low ({lo:g}) must not exceed speed_band_high ({hi:g})")
    if target_speeds is not None:
        ts = np.asarray(target_speeds, np.float64)
        if ts.ndim != 1 or ts.size < 2 or not np.all(np.diff(ts) > 0) or not np.all(np.isfinite(ts)):
            raise ValueError(f"{name}: target_speeds must be an increasing list of at least 2 finite speeds, "
                             f"got {target_speeds!r}")
        fields["target_speeds"] = ts
    params = params.replace(idm=CV.idm_params(name, idm), **fields)
    return RoundaboutAgentsEnv(task, params)
