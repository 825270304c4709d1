"""racetrack-v0 as the authors coded it (docs/scenarios.md, racetrack).

A two-lane circuit (width 5 m, nine sections a->b->...->i->a, 18 lanes) built
with highway-env's exact constructors, including the small joint mismatches of
the original (outer g->h ends at 165 deg but h->i starts at 170 deg; h->i ends
at 56/58 deg; i->a starts at 240/238 deg). The leader starts on the inner lane
(a,b,0) and the follower beside it on the outer lane (a,b,1), both 35 m along
the lane, heading 0, at 10 m/s. Plain vehicles with continuous actions, by
default lateral only: the action is the steering and the speed stays 10 m/s.
Decisions at 5 Hz (3 frames each) over 40 s, i.e. at most 200 steps.

Per-agent reward (``RacetrackEnv._reward`` with that agent's own action):
``lmap(w_c / (1 + k lat^2) + w_a |a_i| + w_x crashed + w_o on_road, [w_x, 1], [0, 1]) * on_road``
with ``lat`` the lateral offset on the closest lane, ``w_c = 1, k = 4, w_a = -0.3,
w_x = -1, w_o = 0``. Cost ``crashed + 0.5 * off_road``. An agent terminates on
crash or leaving the road.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import lanes as L
from envs_jax.env import EnvParams, Scenario
from envs_jax.road import RoadNetwork
from envs_jax.scenarios.continuous import ContinuousScenario

C, S, N = L.LINE_CONTINUOUS, L.LINE_STRIPED, L.LINE_NONE


@struct.dataclass
class RacetrackParams(EnvParams):
    start_s: float = 35.0  # both cars start this far along their lane of a->b
    lane_centering_reward: float = 1.0
    lane_centering_cost: float = 4.0
    action_reward: float = -0.3  # times |a_i|
    collision_reward: float = -1.0  # also the lower end of the reward normalisation
    on_road_reward: float = 0.0  # the authors' config has none (config.get -> 0)
    offroad_cost: float = 0.5  # cost = collision_cost * crashed + offroad_cost * off_road
    terminate_off_road: float = 1.0  # nonzero: leaving the road terminates the agent


def build_road():
    """``RacetrackEnv._make_road`` (same lanes, same insertion order, same arithmetic)."""
    kw = dict(width=5, speed_limit=10.0)
    rad = np.deg2rad
    net = RoadNetwork()
    # 1 - straight
    net.add_lane("a", "b", L.straight([42, 0], [100, 0], line_types=(C, S), **kw))
    net.add_lane("a", "b", L.straight([42, 5], [100, 5], line_types=(S, C), **kw))
    # 2 - circular arc #1
    center1, radii1 = [100, -20], 20
    net.add_lane("b", "c", L.circular(center1, radii1, rad(90), rad(-1), clockwise=False, line_types=(C, N), **kw))
    net.add_lane("b", "c", L.circular(center1, radii1 + 5, rad(90), rad(-1), clockwise=False, line_types=(S, C),
                                      **kw))
    # 3 - vertical straight
    net.add_lane("c", "d", L.straight([120, -20], [120, -30], line_types=(C, N), **kw))
    net.add_lane("c", "d", L.straight([125, -20], [125, -30], line_types=(S, C), **kw))
    # 4 - circular arc #2
    center2, radii2 = [105, -30], 15
    net.add_lane("d", "e", L.circular(center2, radii2, rad(0), rad(-181), clockwise=False, line_types=(C, N), **kw))
    net.add_lane("d", "e", L.circular(center2, radii2 + 5, rad(0), rad(-181), clockwise=False, line_types=(S, C),
                                      **kw))
    # 5 - circular arc #3 (clockwise)
    center3, radii3 = [70, -30], 15
    net.add_lane("e", "f", L.circular(center3, radii3 + 5, rad(0), rad(136), clockwise=True, line_types=(C, S),
                                      **kw))
    net.add_lane("e", "f", L.circular(center3, radii3, rad(0), rad(137), clockwise=True, line_types=(N, C), **kw))
    # 6 - slant
    net.add_lane("f", "g", L.straight([55.7, -15.7], [35.7, -35.7], line_types=(C, N), **kw))
    net.add_lane("f", "g", L.straight([59.3934, -19.2], [39.3934, -39.2], line_types=(S, C), **kw))
    # 7 - circular arc #4, in two sections
    center4, radii4 = [18.1, -18.1], 25
    net.add_lane("g", "h", L.circular(center4, radii4, rad(315), rad(170), clockwise=False, line_types=(C, N),
                                      **kw))
    net.add_lane("g", "h", L.circular(center4, radii4 + 5, rad(315), rad(165), clockwise=False, line_types=(S, C),
                                      **kw))
    net.add_lane("h", "i", L.circular(center4, radii4, rad(170), rad(56), clockwise=False, line_types=(C, N), **kw))
    net.add_lane("h", "i", L.circular(center4, radii4 + 5, rad(170), rad(58), clockwise=False, line_types=(S, C),
                                      **kw))
    # 8 - circular arc #5 (clockwise), back to the start
    center5, radii5 = [43.2, 23.4], 18.5
    net.add_lane("i", "a", L.circular(center5, radii5 + 5, rad(240), rad(270), clockwise=True, line_types=(C, S),
                                      **kw))
    net.add_lane("i", "a", L.circular(center5, radii5, rad(238), rad(268), clockwise=True, line_types=(N, C), **kw))
    return net.freeze()


class Racetrack(ContinuousScenario, Scenario):
    name = "racetrack"
    discrete = False
    default_action_mode = "lateral"
    road_order = (0, 1)
    simulation_frequency = 15
    policy_frequency = 5
    params_cls = RacetrackParams
    # Keys of the authors' env_config.json that the multi-agent step never reads
    # (docs/scenarios.md, 'Where we follow the authors' code').
    inert_config_keys = frozenset({"other_vehicles", "speed_limit", "terminate_off_road"})

    def __init__(self, action_mode: str | None = None):
        self._set_action_mode(action_mode)
        self.road = build_road()
        self.start_lanes = np.array([self.road.lane("a", "b", 0), self.road.lane("a", "b", 1)], np.int32)

    def default_params(self) -> RacetrackParams:
        table = self.road.lanes
        return RacetrackParams(
            duration=40.0, collision_cost=1.0,
            init_x=None, init_y=None,  # positions come from start_s along (a,b,0) and (a,b,1)
            init_heading=table.np_col("heading")[self.start_lanes].copy(),  # lane.heading_at(35)
            init_speed=table.np_col("speed_limit")[self.start_lanes].copy(),  # speed=None -> 10 m/s
            init_target_speed=None, target_speeds=None,
            obstacles=np.zeros((0, 5)),
        )

    def initial_vehicles(self, key, params):
        table = self.road.lanes
        col = lambda name: jnp.asarray(table.np_col(name)[self.start_lanes], dtype=L.float_dtype())
        s = jnp.asarray(params.start_s)
        # Vehicle.make_on_lane: StraightLane.position(s, 0) = start + s * direction + 0 * direction_lateral
        x = col("start_x") + s * col("dir_x") + 0.0 * col("lat_x")
        y = col("start_y") + s * col("dir_y") + 0.0 * col("lat_y")
        return dict(x=x, y=y, heading=params.init_heading, speed=params.init_speed)

    def outcome(self, prev, state, action, params):
        dtype = state.x.dtype
        crashed = state.crashed
        on_road = state.on_road
        lat = state.lane_lat
        action = jnp.asarray(action, dtype).reshape(2, -1)
        a_norm = jnp.sqrt(jnp.sum(action * action, axis=-1))
        # RacetrackEnv._reward: sum(weight * term) in dict order, then lmap([collision_reward, 1] -> [0, 1]).
        raw = (params.lane_centering_reward * (1 / (1 + params.lane_centering_cost * lat ** 2))
               + params.action_reward * a_norm + params.collision_reward * crashed
               + params.on_road_reward * on_road)
        lo = params.collision_reward
        reward = (0.0 + (raw - lo) * (1.0 - 0.0) / (1.0 - lo)) * on_road
        cost = params.collision_cost * crashed + params.offroad_cost * ~on_road
        terminate_off_road = jnp.asarray(params.terminate_off_road) != 0
        terminated = crashed | (terminate_off_road & ~on_road)
        info = {"crash": jnp.any(crashed)}
        return reward.astype(dtype), cost.astype(dtype), terminated, state, info
