"""intersection-v1 (``ContinuousIntersectionEnv``) as the authors coded it (docs/scenarios.md, intersection).

A four-way junction: for each corner an approach lane, a right turn, a left
turn, a straight crossing and an exit lane (20 lanes), built with highway-env's
rotation matrices so that the floating-point round-off of the rotated corners
is reproduced bit for bit (e.g. the west approach lies at y = 2.0000000000000067).
The leader starts on the south approach ``o0->ir0`` heading north, the follower
on the west approach ``o1->ir1`` heading east, each at ``start_s + start_noise * N(0, 1)``
metres along its lane (the fork's ``60 + N(1, 1)``, drawn here from the reset
key so runs are reproducible), at 10 m/s. Plain vehicles with continuous
actions; by default longitudinal only (steering 0, so each car can only go
straight: the leader to exit ``o2``, the follower to ``o3``).

Per-agent reward: -5 while crashed, +2 while 8 <= speed <= 12, and a one-shot
arrival bonus (+5 to the first, +2 to the second; leader evaluated first) on
reaching its exit lane at s >= 5. Cost ``5 * crashed``. An agent terminates on
crash, arrival, or leaving the road (``offroad_terminal``).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import lanes as L
from envs_jax.env import EnvParams, Scenario
from envs_jax.road import RoadNetwork
from envs_jax.scenarios.arrival import one_shot_arrival
from envs_jax.scenarios.continuous import ContinuousScenario

C, S, N = L.LINE_CONTINUOUS, L.LINE_STRIPED, L.LINE_NONE


@struct.dataclass
class IntersectionParams(EnvParams):
    start_s: Any = None  # [2] mean start offset along each approach lane (the fork: 60 + E[N(1, 1)] = 61)
    start_noise: float = 1.0  # std of the Gaussian added to start_s at reset (0: deterministic)
    collision_reward: float = -5.0  # per step while crashed
    speed_reward: float = 2.0  # while speed_band_low <= speed <= speed_band_high
    speed_band_low: float = 8.0
    speed_band_high: float = 12.0
    first_arrival_reward: float = 5.0  # one-shot
    second_arrival_reward: float = 2.0  # one-shot
    arrival_s: float = 5.0  # arrived: on the agent's exit lane with s >= arrival_s
    offroad_terminal: float = 1.0  # nonzero: leaving the road terminates the agent


def build_road():
    """``IntersectionEnv._make_road`` (same lanes, same insertion order, same arithmetic)."""
    lane_width = L.DEFAULT_WIDTH
    right_turn_radius = lane_width + 5
    left_turn_radius = right_turn_radius + lane_width
    outer_distance = right_turn_radius + lane_width / 2
    access_length = 50 + 50
    kw = dict(speed_limit=10.0)
    net = RoadNetwork()
    for corner in range(4):
        angle = np.radians(90 * corner)
        rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
        # Incoming
        start = rotation @ np.array([lane_width / 2, access_length + outer_distance])
        end = rotation @ np.array([lane_width / 2, outer_distance])
        net.add_lane(f"o{corner}", f"ir{corner}", L.straight(start, end, line_types=[S, C], **kw))
        # Right turn
        r_center = rotation @ (np.array([outer_distance, outer_distance]))
        net.add_lane(f"ir{corner}", f"il{(corner - 1) % 4}",
                     L.circular(r_center, right_turn_radius, angle + np.radians(180), angle + np.radians(270),
                                line_types=[N, C], **kw))
        # Left turn
        l_center = rotation @ (np.array([-left_turn_radius + lane_width / 2, left_turn_radius - lane_width / 2]))
        net.add_lane(f"ir{corner}", f"il{(corner + 1) % 4}",
                     L.circular(l_center, left_turn_radius, angle + np.radians(0), angle + np.radians(-90),
                                clockwise=False, line_types=[N, N], **kw))
        # Straight
        start = rotation @ np.array([lane_width / 2, outer_distance])
        end = rotation @ np.array([lane_width / 2, -outer_distance])
        net.add_lane(f"ir{corner}", f"il{(corner + 2) % 4}", L.straight(start, end, line_types=[S, N], **kw))
        # Exit
        start = rotation @ np.flip([lane_width / 2, access_length + outer_distance], axis=0)
        end = rotation @ np.flip([lane_width / 2, outer_distance], axis=0)
        net.add_lane(f"il{(corner - 1) % 4}", f"o{(corner - 1) % 4}", L.straight(end, start, line_types=[N, C], **kw))
    return net.freeze()


class Intersection(ContinuousScenario, Scenario):
    name = "intersection"
    discrete = False
    default_action_mode = "longitudinal"
    road_order = (0, 1)
    simulation_frequency = 15
    policy_frequency = 1
    params_cls = IntersectionParams
    # Keys of the authors' env_config.json that the multi-agent step never reads
    # (docs/scenarios.md, 'Where we follow the authors' code').
    inert_config_keys = frozenset({"arrived_reward", "collision_reward", "high_speed_reward", "on_road_reward",
                                   "first_arrive_reward", "second_arrive_reward", "reward_speed_range",
                                   "destination", "initial_vehicle_count", "spawn_probability"})

    def __init__(self, action_mode: str | None = None):
        self._set_action_mode(action_mode)
        self.road = build_road()
        # Approach lanes (leader: south o0->ir0, follower: west o1->ir1) and exit lanes (il2->o2, il3->o3).
        self.start_lanes = np.array([self.road.lane("o0", "ir0", 0), self.road.lane("o1", "ir1", 0)], np.int32)
        self.goal_lanes = np.array([self.road.lane("il2", "o2", 0), self.road.lane("il3", "o3", 0)], np.int32)

    def default_params(self) -> IntersectionParams:
        table = self.road.lanes
        return IntersectionParams(
            duration=20.0, collision_cost=5.0,
            init_x=None, init_y=None,  # positions come from start_s along the approach lanes
            init_heading=table.np_col("heading")[self.start_lanes].copy(),  # lane.heading_at(60)
            init_speed=table.np_col("speed_limit")[self.start_lanes].copy(),  # 10 m/s
            init_target_speed=None, target_speeds=None,
            obstacles=np.zeros((0, 5)),
            start_s=np.array([61.0, 61.0]), start_noise=1.0,
        )

    def start_offsets(self, key, params):
        """Start offsets ``[2]`` along the approach lanes: ``start_s + start_noise * N(0, 1)`` from ``key``."""
        start_s = jnp.asarray(params.start_s)
        noise = jax.random.normal(key, start_s.shape, dtype=start_s.dtype)
        return start_s + params.start_noise * noise

    def initial_vehicles(self, key, params):
        s = self.start_offsets(key, params)
        table = self.road.lanes
        col = lambda name: jnp.asarray(table.np_col(name)[self.start_lanes], dtype=L.float_dtype())
        # StraightLane.position(s, 0) = start + s * direction + 0 * direction_lateral
        x = col("start_x") + s * col("dir_x") + 0.0 * col("lat_x")
        y = col("start_y") + s * col("dir_y") + 0.0 * col("lat_y")
        return dict(x=x, y=y, heading=params.init_heading, speed=params.init_speed)

    def outcome(self, prev, state, action, params):
        dtype = state.x.dtype
        crashed = state.crashed
        in_band = (state.speed >= params.speed_band_low) & (state.speed <= params.speed_band_high)
        reward = params.collision_reward * crashed + params.speed_reward * in_band
        here = (state.lane == jnp.asarray(self.goal_lanes)) & (state.lane_s >= params.arrival_s)
        bonus, arrived, first = one_shot_arrival(here, state.arrived, state.first_arrived,
                                                 params.first_arrival_reward, params.second_arrival_reward)
        reward = (reward + bonus).astype(dtype)
        cost = (params.collision_cost * crashed).astype(dtype)
        offroad_terminal = jnp.asarray(params.offroad_terminal) != 0
        terminated = crashed | here | (offroad_terminal & ~state.on_road)
        state = state.replace(arrived=arrived, first_arrived=first)
        info = {"crash": jnp.any(crashed), "leader_arrived": arrived[0], "follower_arrived": arrived[1],
                "first_arrived": state.first_arrived, "at_exit": here}
        return reward, cost, terminated, state, info
