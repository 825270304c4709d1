"""merge-v0 as the authors coded it (docs/scenarios.md, merge).

A two-lane highway (a->b->c->d) joined by a ramp (j->k->b) whose merge lane
(b->c, id 2) ends at a 2x2 m obstacle at (310, 8). The leader drives on the
highway at (70, 4), the follower on the ramp at (70, 14.5), both at 25 m/s with
MDP meta-actions over target speeds [20, 25, 30]. No other traffic.

Per-agent reward: +2 while the target-speed index is >= 1, -5 per step while
crashed, and a one-shot arrival bonus when crossing x > 350: +10 to the first
to arrive, +5 to the second (leader evaluated first, so a tie goes to it).
Cost ``5 * crashed``; an agent terminates on crash or arrival.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import lanes as L
from envs_jax.env import EnvParams, Scenario
from envs_jax.road import RoadNetwork
from envs_jax.scenarios.arrival import one_shot_arrival

C, S, N = L.LINE_CONTINUOUS_LINE, L.LINE_STRIPED, L.LINE_NONE


@struct.dataclass
class MergeParams(EnvParams):
    speed_reward: float = 2.0  # while target-speed index >= 1
    collision_reward: float = -5.0  # per step while crashed
    first_arrival_reward: float = 10.0
    second_arrival_reward: float = 5.0
    finish_x: float = 350.0


def build_road():
    """``MergeEnv._make_road`` (same lanes, same insertion order)."""
    net = RoadNetwork()
    ends = [150, 80, 80, 150]
    y = [0, L.DEFAULT_WIDTH]
    line_type = [[C, S], [N, C]]
    line_type_merge = [[C, S], [N, S]]
    for i in range(2):
        net.add_lane("a", "b", L.straight([0, y[i]], [sum(ends[:2]), y[i]], line_types=line_type[i]))
        net.add_lane("b", "c", L.straight([sum(ends[:2]), y[i]], [sum(ends[:3]), y[i]],
                                          line_types=line_type_merge[i]))
        net.add_lane("c", "d", L.straight([sum(ends[:3]), y[i]], [sum(ends), y[i]], line_types=line_type[i]))
    amplitude = 3.25
    ramp_y = 6.5 + 4 + 4
    net.add_lane("j", "k", L.straight([0, ramp_y], [ends[0], ramp_y], line_types=[C, C], forbidden=True))
    # SineLane(ljk.position(150, -A), ljk.position(230, -A), A, 2 pi / 160, pi / 2)
    net.add_lane("k", "b", L.sine([ends[0], ramp_y - amplitude], [sum(ends[:2]), ramp_y - amplitude],
                                  amplitude, 2 * np.pi / (2 * ends[1]), np.pi / 2,
                                  line_types=[C, C], forbidden=True))
    # lbc starts at lkb.position(80, 0); computed like highway-env (start + s dir + A sin(w s + phase) lat).
    kb_start = np.array([ends[0], ramp_y - amplitude])
    kb_end = np.array([sum(ends[:2]), ramp_y - amplitude])
    direction = (kb_end - kb_start) / np.linalg.norm(kb_end - kb_start)
    lateral = np.array([-direction[1], direction[0]])
    offset = amplitude * np.sin(2 * np.pi / (2 * ends[1]) * ends[1] + np.pi / 2)
    lbc_start = kb_start + ends[1] * direction + offset * lateral
    net.add_lane("b", "c", L.straight(lbc_start, lbc_start + [ends[2], 0], line_types=[N, C], forbidden=True))
    obstacle = lbc_start + [ends[2], 0]
    return net.freeze(), obstacle


class Merge(Scenario):
    name = "merge"
    discrete = True
    road_order = (0, 1)
    simulation_frequency = 15
    policy_frequency = 1
    params_cls = MergeParams
    inert_config_keys = frozenset({"collision_reward", "right_lane_reward", "high_speed_reward",
                                   "reward_speed_range", "merging_speed_reward", "lane_change_reward",
                                   "on_road_reward"})

    def __init__(self):
        self.road, self.obstacle = build_road()

    def default_params(self) -> MergeParams:
        return MergeParams(
            duration=20.0, collision_cost=5.0,
            init_x=np.array([70.0, 70.0]), init_y=np.array([4.0, 14.5]),
            init_heading=np.array([0.0, 0.0]), init_speed=np.array([25.0, 25.0]),
            init_target_speed=None,
            target_speeds=np.array([20.0, 25.0, 30.0]),
            obstacles=np.array([[self.obstacle[0], self.obstacle[1], 0.0, 2.0, 2.0]]),
        )

    def initial_vehicles(self, key, params):
        return dict(x=params.init_x, y=params.init_y, heading=params.init_heading,
                    speed=params.init_speed, target_speed=params.init_target_speed)

    def outcome(self, prev, state, action, params):
        crashed = state.crashed
        reward = params.speed_reward * (state.speed_index >= 1) + params.collision_reward * crashed
        beyond = state.x > params.finish_x
        bonus, arrived, first = one_shot_arrival(beyond, state.arrived, state.first_arrived,
                                                 params.first_arrival_reward, params.second_arrival_reward)
        reward = (reward + bonus).astype(state.x.dtype)
        cost = (params.collision_cost * crashed).astype(state.x.dtype)
        terminated = crashed | beyond
        crash = jnp.any(crashed)
        state = state.replace(arrived=arrived, first_arrived=first)
        info = {"crash": crash, "leader_arrived": arrived[0] & ~crash, "follower_arrived": arrived[1] & ~crash,
                "first_arrived": state.first_arrived}
        return reward, cost, terminated, state, info
