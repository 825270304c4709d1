"""roundabout-v0 as the authors coded it (docs/scenarios.md, roundabout).

A two-lane ring (radii 20 and 24 m, eight arcs) with four single-lane sine
access and exit roads. The leader enters from the west at (-45, 2), the
follower from the south at (2, 85), both at 8 m/s with MDP meta-actions over
target speeds [0, 4, 8, 12, 16], and both are routed to the north exit
(leader: three quarters of the ring, follower: half). ``road.vehicles`` is
``[follower, leader]``, which orders the collision checks.

Per-agent reward: -5 per step while crashed, +2 while 10 <= speed <= 15 and
+5 on *every* step while on the north exit road ``nxs->nxr`` at s >= 20.
Cost ``5 * crashed``; an agent terminates on crash or arrival.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import lanes as L
from envs_jax.env import EnvParams, Scenario
from envs_jax.road import RoadNetwork

C, S, N = L.LINE_CONTINUOUS, L.LINE_STRIPED, L.LINE_NONE


@struct.dataclass
class RoundaboutParams(EnvParams):
    collision_reward: float = -5.0  # per step while crashed
    speed_reward: float = 2.0  # while speed_band_low <= speed <= speed_band_high
    speed_band_low: float = 10.0
    speed_band_high: float = 15.0
    arrival_reward: float = 5.0  # every step while arrived
    arrival_s: float = 20.0  # arrived: on lane nxs->nxr with s >= arrival_s


def build_road():
    """``RoundaboutEnv._make_road`` (same lanes, same insertion order)."""
    net = RoadNetwork()
    center = [0, 0]
    radius = 20
    alpha = 24
    radii = [radius, radius + 4]
    line = [[C, S], [N, C]]
    rad = np.deg2rad
    arcs = [("se", "ex", 90 - alpha, alpha), ("ex", "ee", alpha, -alpha), ("ee", "nx", -alpha, -90 + alpha),
            ("nx", "ne", -90 + alpha, -90 - alpha), ("ne", "wx", -90 - alpha, -180 + alpha),
            ("wx", "we", -180 + alpha, -180 - alpha), ("we", "sx", 180 - alpha, 90 + alpha),
            ("sx", "se", 90 + alpha, 90 - alpha)]
    for lane in [0, 1]:
        for f, t, a0, a1 in arcs:
            net.add_lane(f, t, L.circular(center, radii[lane], rad(a0), rad(a1), clockwise=False,
                                          line_types=line[lane]))
    access, dev, a = 170, 85, 5
    delta_st = 0.2 * dev
    delta_en = dev - delta_st
    w = 2 * np.pi / dev
    exit_phase = -np.pi / 2 + w * delta_en
    net.add_lane("ser", "ses", L.straight([2, access], [2, dev / 2], line_types=(S, C)))
    net.add_lane("ses", "se",
                 L.sine([2 + a, dev / 2], [2 + a, dev / 2 - delta_st], a, w, -np.pi / 2, line_types=(C, C)))
    net.add_lane("sx", "sxs", L.sine([-2 - a, -dev / 2 + delta_en], [-2 - a, dev / 2], a, w, exit_phase,
                                     line_types=(C, C)))
    net.add_lane("sxs", "sxr", L.straight([-2, dev / 2], [-2, access], line_types=(N, C)))
    net.add_lane("eer", "ees", L.straight([access, -2], [dev / 2, -2], line_types=(S, C)))
    net.add_lane("ees", "ee", L.sine([dev / 2, -2 - a], [dev / 2 - delta_st, -2 - a], a, w, -np.pi / 2,
                                     line_types=(C, C)))
    net.add_lane("ex", "exs", L.sine([-dev / 2 + delta_en, 2 + a], [dev / 2, 2 + a], a, w, exit_phase,
                                     line_types=(C, C)))
    net.add_lane("exs", "exr", L.straight([dev / 2, 2], [access, 2], line_types=(N, C)))
    net.add_lane("ner", "nes", L.straight([-2, -access], [-2, -dev / 2], line_types=(S, C)))
    net.add_lane("nes", "ne", L.sine([-2 - a, -dev / 2], [-2 - a, -dev / 2 + delta_st], a, w, -np.pi / 2,
                                     line_types=(C, C)))
    net.add_lane("nx", "nxs", L.sine([2 + a, dev / 2 - delta_en], [2 + a, -dev / 2], a, w, exit_phase,
                                     line_types=(C, C)))
    net.add_lane("nxs", "nxr", L.straight([2, -dev / 2], [2, -access], line_types=(N, C)))
    net.add_lane("wer", "wes", L.straight([-access, 2], [-dev / 2, 2], line_types=(S, C)))
    net.add_lane("wes", "we", L.sine([-dev / 2, 2 + a], [-dev / 2 + delta_st, 2 + a], a, w, -np.pi / 2,
                                     line_types=(C, C)))
    net.add_lane("wx", "wxs", L.sine([dev / 2 - delta_en, -2 - a], [-dev / 2, -2 - a], a, w, exit_phase,
                                     line_types=(C, C)))
    net.add_lane("wxs", "wxr", L.straight([-dev / 2, -2], [-access, -2], line_types=(N, C)))
    return net.freeze()


LEADER_ROUTE = ["wer", "wes", "we", "sx", "se", "ex", "ee", "nx", "nxs"]
FOLLOWER_ROUTE = ["ser", "ses", "se", "ex", "ee", "nx", "nxs"]


class Roundabout(Scenario):
    name = "roundabout"
    discrete = True
    road_order = (1, 0)  # road.vehicles = [follower, leader]
    simulation_frequency = 15
    policy_frequency = 1
    params_cls = RoundaboutParams
    inert_config_keys = frozenset({"collision_reward", "high_speed_reward", "right_lane_reward",
                                   "lane_change_reward", "normalize_reward", "incoming_vehicle_destination",
                                   "reward_speed_range"})

    def __init__(self):
        self.road = build_road()
        self.route_length = len(LEADER_ROUTE) - 1
        lr = self.road.route(LEADER_ROUTE, first_lane_id=0, length=self.route_length)
        fr = self.road.route(FOLLOWER_ROUTE, first_lane_id=0, length=self.route_length)
        self.routes = (np.stack([lr[0], fr[0]]), np.stack([lr[1], fr[1]]), np.array([lr[2], fr[2]], np.int32))
        self.goal_lane = self.road.lane("nxs", "nxr", 0)

    def default_params(self) -> RoundaboutParams:
        return RoundaboutParams(
            duration=20.0, collision_cost=5.0,
            init_x=np.array([-45.0, 2.0]), init_y=np.array([2.0, 85.0]),
            init_heading=np.array([0.0, -np.pi / 2]), init_speed=np.array([8.0, 8.0]),
            init_target_speed=None,
            target_speeds=np.array([0.0, 4.0, 8.0, 12.0, 16.0]),
            obstacles=np.zeros((0, 5)),
        )

    def initial_vehicles(self, key, params):
        return dict(x=params.init_x, y=params.init_y, heading=params.init_heading,
                    speed=params.init_speed, target_speed=params.init_target_speed, routes=self.routes)

    def outcome(self, prev, state, action, params):
        crashed = state.crashed
        arrived = (state.lane == self.goal_lane) & (state.lane_s >= params.arrival_s)
        in_band = (state.speed >= params.speed_band_low) & (state.speed <= params.speed_band_high)
        reward = (params.collision_reward * crashed + params.speed_reward * in_band
                  + params.arrival_reward * arrived).astype(state.x.dtype)
        cost = (params.collision_cost * crashed).astype(state.x.dtype)
        terminated = crashed | arrived
        state = state.replace(arrived=arrived)
        info = {"crash": jnp.any(crashed), "leader_arrived": arrived[0], "follower_arrived": arrived[1]}
        return reward, cost, terminated, state, info
