"""The authors' intersection with K controlled agents, on the traffic core (docs/scenarios.md).

``envs_jax.make("intersection-k", controlled_vehicles=K)``, K in 2..8.

Road, dynamics, actions, reward, cost and termination are those of the two-agent
``intersection`` (:mod:`envs_jax.scenarios.intersection`), generalised per agent: the
four-way junction without traffic lights, plain vehicles with continuous actions
(longitudinal only by default: steering 0, so each car drives straight across), one
decision per second over 15 frames, 20 s episodes.

Placement, one agent per arm: agent k approaches from arm ``k % 4`` (0 south heading north,
1 west heading east, 2 north heading south, 3 east heading west), ``start_s[k] + start_noise *
N(0, 1)`` m along that arm's approach lane ``o{arm} -> ir{arm}`` (default ``start_s`` 61 m for
agents 0-3 and 41 m for agents 4-7, a second wave 20 m behind the first; the noise from the reset
key), at 10 m/s; its exit is the opposite arm's, ``il{arm + 2} -> o{arm + 2}``. Agents 0 and 1 are
the two-agent leader and follower. Slots hold the agents in agent order (the order of highway-env's
vehicle list, which orders the collision checks, as the two-agent ``[leader, follower]``).

Per agent k: ``collision_reward`` (-5) on every step while crashed, ``speed_reward`` (2) while
``8 <= speed <= 12`` m/s, and a one-shot arrival bonus on first reaching its exit lane at
``s >= arrival_s`` (5 m), ranked (:func:`envs_jax.scenarios.arrival.ranked_arrival`): the first
agent to arrive gets ``first_arrival_reward`` (5), every later one ``second_arrival_reward`` (2),
agents arriving on the same step ranked in agent order. Cost ``collision_cost * crashed`` (5).
Agent k terminates on a crash, at its exit, or off the road (``offroad_terminal``); the episode
ends when every agent has terminated or at the time limit.

Observation ``[K, 4 * vehicles_count]`` (default ``vehicles_count = K``): the authors' absolute,
unnormalised ``[x, y, vx, vy]`` rows, agent k's own first, then the nearest other agents, nearest
first, ties in agent order (:mod:`envs_jax.nearest_view`); with K = 2 the two-agent ``[2, 8]`` view.
There is no background traffic here: highway-env's intersection traffic, which yields by priority
and enters and leaves during an episode, is ``intersection-v0`` / ``intersection-v1``.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import lanes as L
from envs_jax import nearest_view
from envs_jax.continuous_traffic_env import ContinuousTrafficEnv
from envs_jax.scenarios import config_values as CV
from envs_jax.scenarios.arrival import ArrivalBookkeeping, ArrivalState, ranked_arrival
from envs_jax.scenarios.continuous import action_flags
from envs_jax.scenarios.intersection import build_road
from envs_jax.traffic_env import Task, TrafficParams

NAME = "intersection-k"
MIN_AGENTS, MAX_AGENTS = 2, 8
ARMS = 4
START_S = 61.0  # the two-agent mean start along the approach lane [m]
WAVE_SPACING = 20.0  # agents 4..7 start this much further back on the same arms [m]
ACTION_MODES = ("longitudinal", "lateral", "both")


@struct.dataclass
class IntersectionAgentsParams(TrafficParams):
    start_s: Any = None  # [K] mean start offset along each agent's approach lane
    start_noise: float = 1.0  # std of the Gaussian added to start_s at reset (0: deterministic)
    collision_reward: float = -5.0  # per step while crashed
    speed_reward: float = 2.0  # while speed_band_low <= speed <= speed_band_high
    speed_band_low: float = 8.0
    speed_band_high: float = 12.0
    first_arrival_reward: float = 5.0  # one-shot, the first agent to arrive
    second_arrival_reward: float = 2.0  # one-shot, every later one
    arrival_s: float = 5.0  # arrived: on the agent's exit lane with s >= arrival_s
    offroad_terminal: bool = True  # leaving the road terminates the agent
    acceleration_range: Any = (-5.0, 5.0)  # m/s^2, action -1..1 mapped linearly (the two-agent scenarios')
    steering_range: Any = (-np.pi / 4, np.pi / 4)  # rad


class IntersectionAgentsTask(Task):
    """The authors' intersection with ``k`` agents (module docstring)."""

    route_length = 1

    def __init__(self, k: int, vehicles_count: int, longitudinal: bool, lateral: bool,
                 simulation_frequency: int = 15, policy_frequency: int = 1):
        self.name = NAME
        self.road = build_road()
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.longitudinal, self.lateral = longitudinal, lateral
        self.num_agents = k
        self.num_slots = k
        self.controlled = tuple(range(k))
        self.view_order = self.controlled  # slots hold the agents only
        self.vehicles_count = vehicles_count
        arm = np.arange(k) % ARMS
        self.start_lanes = np.array([self.road.lane(f"o{a}", f"ir{a}", 0) for a in arm], np.int32)
        self.goal_lanes = np.array([self.road.lane(f"il{(a + 2) % ARMS}", f"o{(a + 2) % ARMS}", 0) for a in arm],
                                   np.int32)

    def default_params(self) -> IntersectionAgentsParams:
        k = self.num_agents
        return IntersectionAgentsParams(duration=20.0, collision_cost=5.0, target_speeds=np.array([0.0, 5.0, 10.0]),
                                        obstacles=None,
                                        start_s=START_S - WAVE_SPACING * (np.arange(k) // ARMS).astype(np.float64))

    def initial_vehicles(self, key, params: IntersectionAgentsParams) -> dict:
        """Each agent ``start_s + start_noise * N(0, 1)`` m along its approach lane (the two-agent draw)."""
        dtype = L.float_dtype()
        start_s = jnp.asarray(params.start_s, dtype)
        s = start_s + params.start_noise * jax.random.normal(key, start_s.shape, dtype=dtype)
        lanes = self.road.lanes
        col = lambda name: jnp.asarray(lanes.np_col(name)[self.start_lanes], dtype)
        # StraightLane.position(s, 0) = start + s * direction + 0 * direction_lateral
        x = col("start_x") + s * col("dir_x") + 0.0 * col("lat_x")
        y = col("start_y") + s * col("dir_y") + 0.0 * col("lat_y")
        k = self.num_agents
        return dict(x=x, y=y, heading=col("heading"), speed=col("speed_limit"), alive=jnp.ones(k, bool),
                    delta=jnp.full(k, params.idm.delta, dtype))

    def outcome(self, prev, state: ArrivalState, action, params: IntersectionAgentsParams):
        """The two-agent intersection's outcome per agent; the arrival flags go back through ``info``
        (:class:`IntersectionAgentsEnv` stores them in the state)."""
        dtype = state.x.dtype
        crashed, on_road, speed = state.crashed, state.on_road, state.speed
        in_band = (speed >= params.speed_band_low) & (speed <= params.speed_band_high)
        reward = params.collision_reward * crashed + params.speed_reward * in_band
        s, _ = L.local_coordinates(self.road.lanes, state.lane, state.x, state.y)
        here = (state.lane == jnp.asarray(self.goal_lanes)) & (s >= params.arrival_s)
        bonus, arrived, first = ranked_arrival(here, state.arrived, state.first_arrived,
                                               params.first_arrival_reward, params.second_arrival_reward)
        reward = (reward + bonus).astype(dtype)
        cost = (params.collision_cost * crashed).astype(dtype)
        terminated = crashed | here | (params.offroad_terminal & ~on_road)
        info = {"crash": jnp.any(crashed), "arrived": arrived, "first_arrived": first, "at_exit": here}
        return reward, cost, terminated, info


class IntersectionAgentsEnv(ArrivalBookkeeping, nearest_view.NearestViewEnv, ContinuousTrafficEnv):
    """:class:`ContinuousTrafficEnv` with the authors' observation and the arrival flags kept in the state."""

    def __init__(self, task: IntersectionAgentsTask, default_params: IntersectionAgentsParams):
        super().__init__(task, default_params)
        self.use_nearest_view()


PARAM_KEYS = ("duration", "collision_cost", "start_noise", "collision_reward", "speed_reward", "speed_band_low",
              "speed_band_high", "first_arrival_reward", "second_arrival_reward", "arrival_s", "offroad_terminal")
# the factory's own keywords besides PARAM_KEYS
FACTORY_KEYS = ("controlled_vehicles", "vehicles_count", "action_mode", "start_s", "simulation_frequency",
                "policy_frequency")


def make_intersection_agents(name: str = NAME, env_config: dict | None = None, *, controlled_vehicles: int = 2,
                             vehicles_count: int | None = None, action_mode: str = "longitudinal",
                             start_s=None, simulation_frequency: int = 15, policy_frequency: int = 1,
                             **values) -> IntersectionAgentsEnv:
    """The authors' intersection with ``controlled_vehicles`` agents (2..8); ``vehicles_count`` rows per
    observation (2..K, default K); ``action_mode`` longitudinal (the authors'), lateral or both; ``start_s``
    (``[K]`` metres along the approach lanes, each in 0..100) and the reward, cost and duration numbers of
    :class:`IntersectionAgentsParams` as keywords. Bad values raise ``ValueError`` naming the key and what is
    allowed."""
    CV.keywords_only(name, env_config, values, PARAM_KEYS, FACTORY_KEYS)
    k, _, count, sim, pol = CV.agents_layout(name, controlled_vehicles, 0, vehicles_count, simulation_frequency,
                                             policy_frequency, MIN_AGENTS, MAX_AGENTS, 0)  # no traffic here
    if action_mode not in ACTION_MODES:
        raise ValueError(f"{name}: action_mode must be one of {', '.join(ACTION_MODES)}, got {action_mode!r}")
    lon, lat = action_flags(action_mode)
    task = IntersectionAgentsTask(k, count, lon, lat, sim, pol)
    params = task.default_params()
    fields: dict[str, Any] = {}
    for key, v in values.items():
        if key == "offroad_terminal":
            fields[key] = CV.flag_value(name, key, v)
        elif key in ("collision_cost", "start_noise", "speed_band_low", "speed_band_high", "arrival_s"):
            fields[key] = CV.cost_value(name, key, v)
        else:
            fields[key] = CV.number_value(name, key, v, positive=key == "duration")
    lo, hi = (fields.get(key, getattr(params, key)) for key in ("speed_band_low", "speed_band_high"))
    if lo > hi:
        raise ValueError(f"{name}: speed_band_low ({lo:g}) must not exceed speed_band_high ({hi:g})")
    if start_s is not None:
        arr = np.asarray(start_s, np.float64)
        if arr.shape != (k,) or not np.all(np.isfinite(arr)) or np.any((arr < 0) | (arr > 100)):
            raise ValueError(f"{name}: start_s must be {k} numbers in 0..100 (metres along each agent's approach "
                             f"lane), got {start_s!r}")
        fields["start_s"] = arr
    return IntersectionAgentsEnv(task, params.replace(**fields))
