"""The authors' racetrack with K controlled agents, on the traffic core (docs/scenarios.md).

``envs_jax.make("racetrack-k", controlled_vehicles=K, other_vehicles=N)``, K in 2..8, N in 0..7.

Road, dynamics, actions, reward and cost are those of the two-agent ``racetrack``
(:mod:`envs_jax.scenarios.racetrack`): the two-lane circuit, plain vehicles with continuous
actions (lateral only by default: the steering, the speed stays 10 m/s), 5 decisions per
second over 15 frames per second, 40 s episodes.

Placement, a starting grid: agent k starts in row ``k // 2`` on lane ``(a, b, k % 2)`` (even
agents on the inner lane, odd ones on the outer lane), ``35 - 10 * (k // 2)`` m along it, heading
along it, at the lane's speed limit (10 m/s). Agents 0 and 1 are the two-agent scenario's leader
and follower; eight agents fill four rows, the last 5 m along the straight.

Traffic (``other_vehicles = N``): IDM drivers (highway-env's class constants, the exponent
``idm.delta``), vehicle j halfway along lane ``j % 2`` of the circuit's section j + 1 (b->c,
c->d, ..., h->i; the last section, i->a, ends where the grid stands), at 7.5 m/s (the middle of
racetrack-v0's 6 + U(0, 3) m/s), each at least 15 m from every other vehicle. Nothing is random:
every reset gives the same state.

Slots: the agents in agent order, then the traffic (the order of highway-env's vehicle list,
which orders the collision checks, as the two-agent ``[leader, follower]``).

Observation ``[K, 4 * vehicles_count]`` (default ``vehicles_count = K``): the authors' absolute,
unnormalised ``[x, y, vx, vy]`` rows, agent k's own first, then the nearest other vehicles, agents
or traffic, nearest first, ties in agent order (:mod:`envs_jax.nearest_view`); with K = 2 and no
traffic, the two-agent ``[2, 8]`` view.

Reward and cost per agent, the two-agent terms (racetrack-v0's ``_reward`` with the agent's own
action): ``lmap(w_c / (1 + c lat^2) + w_a |a_k| + w_x crashed + w_o on_road, [w_x, 1], [0, 1]) *
on_road``; cost ``collision_cost * crashed + offroad_cost * off_road``. Agent k terminates on a
crash or off the road; the episode ends when every agent has terminated or at the time limit
(``ceil(duration * policy_frequency)`` steps, as the two-agent scenario).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from envs_jax import lanes as L
from envs_jax import nearest_view
from envs_jax.continuous_traffic_env import ContinuousTrafficEnv
from envs_jax.scenarios import config_values as CV
from envs_jax.scenarios.continuous import action_flags
from envs_jax.scenarios.racetrack import build_road
from envs_jax.scenarios.racetrack_traffic import RacetrackTraffic, RacetrackTrafficParams
from envs_jax.traffic_env import Task

NAME = "racetrack-k"
MIN_AGENTS, MAX_AGENTS = 2, 8
START_S = 35.0  # the first row, as the two-agent scenario [m along (a, b)]
ROW_SPACING = 10.0  # each further row this far behind [m]
TRAFFIC_SPEED = 7.5
SECTIONS = ("a", "b", "c", "d", "e", "f", "g", "h", "i")
MAX_TRAFFIC = len(SECTIONS) - 2  # one vehicle on each section from b->c to h->i
ACTION_MODES = ("lateral", "longitudinal", "both")


class RacetrackAgentsTask(Task):
    """The authors' racetrack with ``k`` agents and ``n`` IDM vehicles (module docstring)."""

    route_length = 1

    def __init__(self, k: int, n: int, vehicles_count: int, longitudinal: bool, lateral: bool,
                 simulation_frequency: int = 15, policy_frequency: int = 5):
        self.name = NAME
        self.road = build_road()
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.longitudinal, self.lateral = longitudinal, lateral
        self.num_agents, self.num_traffic = k, n
        self.num_slots = k + n
        self.controlled = tuple(range(k))
        self.view_order = tuple(range(k + n))  # the agents in agent order, then the traffic
        self.vehicles_count = vehicles_count
        road = self.road
        self.agent_lanes = np.array([road.lane("a", "b", a % 2) for a in range(k)], np.int32)
        self.agent_s = np.array([START_S - ROW_SPACING * (a // 2) for a in range(k)])
        self.traffic_lanes = np.array([road.lane(SECTIONS[j + 1], SECTIONS[(j + 2) % len(SECTIONS)], j % 2)
                                       for j in range(n)], np.int32)
        self.traffic_s = 0.5 * road.lanes.np_col("length")[self.traffic_lanes]

    def default_params(self) -> RacetrackTrafficParams:
        return RacetrackTrafficParams(duration=40.0, collision_cost=1.0, target_speeds=np.array([0.0, 5.0, 10.0]),
                                      obstacles=None)

    def initial_vehicles(self, key, params) -> dict:
        """The deterministic placement of the module docstring (``key`` is not used)."""
        dtype = L.float_dtype()
        lanes = self.road.lanes
        lane = jnp.asarray(np.concatenate([self.agent_lanes, self.traffic_lanes]))
        s = jnp.asarray(np.concatenate([self.agent_s, self.traffic_s]), dtype)
        x, y = L.position(lanes, lane, s, jnp.zeros_like(s))
        heading = L.heading_at(lanes, lane, s)
        speed = jnp.concatenate([lanes.col("speed_limit")[lane[:self.num_agents]].astype(dtype),
                                 jnp.full(self.num_traffic, TRAFFIC_SPEED, dtype)])
        n = self.num_slots
        return dict(x=x, y=y, heading=heading, speed=speed, alive=jnp.ones(n, bool),
                    delta=jnp.full(n, params.idm.delta, dtype))

    outcome = RacetrackTraffic.outcome  # the per-agent racetrack terms (racetrack-v0 and the two-agent scenario)


class RacetrackAgentsEnv(nearest_view.NearestViewEnv, ContinuousTrafficEnv):
    """:class:`ContinuousTrafficEnv` with the authors' observation (:mod:`envs_jax.nearest_view`)."""

    def __init__(self, task: RacetrackAgentsTask, default_params: RacetrackTrafficParams):
        super().__init__(task, default_params)
        self.use_nearest_view()


PARAM_KEYS = ("duration", "collision_cost", "offroad_cost", "collision_reward", "lane_centering_cost",
              "lane_centering_reward", "action_reward", "on_road_reward", "terminate_off_road")
# the factory's own keywords besides PARAM_KEYS
FACTORY_KEYS = ("controlled_vehicles", "other_vehicles", "vehicles_count", "action_mode", "simulation_frequency",
                "policy_frequency", "idm")


def make_racetrack_agents(name: str = NAME, env_config: dict | None = None, *, controlled_vehicles: int = 2,
                          other_vehicles: int = 0, vehicles_count: int | None = None, action_mode: str = "lateral",
                          simulation_frequency: int = 15, policy_frequency: int = 5, idm=None,
                          **values) -> RacetrackAgentsEnv:
    """The authors' racetrack with ``controlled_vehicles`` agents (2..8) and ``other_vehicles`` IDM vehicles
    (0..7); ``vehicles_count`` rows per observation (2..K + N, default K); ``action_mode`` lateral (the
    authors'), longitudinal or both; the reward, cost and duration numbers of the params as keywords and ``idm``
    (an IDMParams or a dict of its fields). Bad values raise ``ValueError`` naming the key and what is allowed."""
    CV.keywords_only(name, env_config, values, PARAM_KEYS, FACTORY_KEYS)
    k, n, count, sim, pol = CV.agents_layout(name, controlled_vehicles, other_vehicles, vehicles_count,
                                             simulation_frequency, policy_frequency, MIN_AGENTS, MAX_AGENTS,
                                             MAX_TRAFFIC)
    if action_mode not in ACTION_MODES:
        raise ValueError(f"{name}: action_mode must be one of {', '.join(ACTION_MODES)}, got {action_mode!r}")
    lon, lat = action_flags(action_mode)
    task = RacetrackAgentsTask(k, n, count, lon, lat, sim, pol)
    params = task.default_params()
    fields = {}
    for key, v in values.items():
        if key == "terminate_off_road":
            CV.flag_value(name, key, v)
            fields[key] = bool(v)
        elif key in ("collision_cost", "offroad_cost", "lane_centering_cost"):
            fields[key] = CV.cost_value(name, key, v)
        else:
            fields[key] = CV.number_value(name, key, v, positive=key == "duration")
    if fields.get("collision_reward", params.collision_reward) == 1.0:
        raise ValueError(f"{name}: collision_reward must differ from 1 (the reward is normalised over "
                         f"[collision_reward, 1])")
    params = params.replace(idm=CV.idm_params(name, idm), **fields)
    return RacetrackAgentsEnv(task, params)
