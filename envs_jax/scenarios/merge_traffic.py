"""``merge-v0`` (highway-env ``envs/merge_env.py``) with IDM traffic and K controlled vehicles.

Road: ``MergeEnv._make_road`` (:func:`envs_jax.scenarios.merge.build_road`): a two-lane
highway a->b->c->d, a ramp j->k->b whose merge lane (b->c, id 2) ends at a 2 x 2 m
obstacle. Vehicles, in list order: the K controlled vehicles (agent order), then
highway-env's traffic: three IDM vehicles on a random lane of a->b at 90, 70 and 5 m
(+ U(-5, 5) m) with speeds 29, 31 and 31.5 m/s (+ U(-1, 1)), and the merging IDM vehicle
on the ramp j->k at 110 m, 20 m/s, target speed 30 m/s. No ``randomize_behavior``
(every driver has ``DELTA = 4``), no routes, no spawning.

Controlled vehicles (highway-env places one; agent 0 is it): agent k starts at row k of
:data:`AGENT_STARTS`, alternating between the ramp (20 m/s, the merging vehicle's speed)
and the highway (30 m/s, the ego's speed) on positions at least 15 m from every
position highway-env's traffic can be drawn at, so no two vehicles overlap at reset:
K is 1 to 9.

Reward of agent k (highway-env's ``_reward`` with vehicle k as the ego and agent k's
own action): collision (crashed), right lane (lane id of the current lane), high speed
(speed mapped from ``reward_speed_range`` to [0, 1], not clipped), lane change (the
action is LANE_LEFT or LANE_RIGHT) and the altruistic merging-speed penalty (the sum,
over the vehicles on the merge lane b->c 2, of ``(target_speed - speed) / target_speed``),
normalised from ``[collision + merging_speed, high_speed + right_lane]`` to [0, 1].
Cost ``collision_cost * crashed``. Agent k terminates when crashed or past x = 370 m;
highway-env's merge has no time limit (``duration`` adds one).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import kinematic_obs
from envs_jax import lanes as L
from envs_jax import vehicle as Veh
from envs_jax.scenarios import config_values as CV
from envs_jax.scenarios.merge import build_road
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams

NAME = "merge-v0"
FINISH_X = 370.0  # _is_terminated: the access ramp has been passed
OBSTACLE_SIZE = 2.0  # RoadObject LENGTH and WIDTH
# (lane, longitudinal [m], speed [m/s]) of agent k; row 0 is highway-env's ego
AGENT_STARTS = (
    (("a", "b", 1), 30.0, 30.0),
    (("j", "k", 0), 30.0, 20.0),
    (("a", "b", 0), 30.0, 30.0),
    (("j", "k", 0), 50.0, 20.0),
    (("a", "b", 1), 50.0, 30.0),
    (("j", "k", 0), 70.0, 20.0),
    (("a", "b", 0), 50.0, 30.0),
    (("j", "k", 0), 10.0, 20.0),
    (("j", "k", 0), 90.0, 20.0),
)
MAX_AGENTS = len(AGENT_STARTS)
# highway-env's traffic on a->b: (longitudinal, speed) before the noise; then the merging vehicle
TRAFFIC = ((90.0, 29.0), (70.0, 31.0), (5.0, 31.5))
MERGING = (110.0, 20.0, 30.0)  # longitudinal on j->k, speed, target speed
NUM_TRAFFIC = len(TRAFFIC) + 1


@struct.dataclass
class MergeTaskParams(TrafficParams):
    collision_reward: float = -1.0
    right_lane_reward: float = 0.1
    high_speed_reward: float = 0.2
    reward_speed_range: Any = (20.0, 30.0)
    merging_speed_reward: float = -0.5
    lane_change_reward: float = -0.05


DEFAULTS = dict(simulation_frequency=15, policy_frequency=1, controlled_vehicles=1, collision_reward=-1,
                right_lane_reward=0.1, high_speed_reward=0.2, reward_speed_range=[20, 30],
                merging_speed_reward=-0.5, lane_change_reward=-0.05)
OWN_KEYS = ("num_slots", "collision_cost", "idm", "duration")


class MergeTask(Task):
    """merge-v0 with ``controlled_vehicles`` agents in ``num_slots`` slots."""

    route_length = 1

    def __init__(self, controlled_vehicles: int, num_slots: int, simulation_frequency: int,
                 policy_frequency: int, obs_config: kinematic_obs.KinematicsConfig):
        self.name = NAME
        self.road, obstacle = build_road()
        self.obstacle = np.asarray(obstacle, np.float64)
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.obs_config = obs_config
        self.num_agents = controlled_vehicles
        self.num_vehicles = controlled_vehicles + NUM_TRAFFIC
        self.num_slots = num_slots
        self.controlled = tuple(range(controlled_vehicles))
        self.merge_lane = self.road.lane("b", "c", 2)
        starts = AGENT_STARTS[:controlled_vehicles]
        # highway-env fixes the default observation y range on the road an observer starts on
        self.obs_range_lanes = tuple(int(self.road.road_num_lanes[self.road.road_index[lane[:2]]])
                                     for lane, _, _ in starts)
        pos = [self._position(lane, s) for lane, s, _ in starts]
        self.agent_x = np.array([p[0] for p in pos])
        self.agent_y = np.array([p[1] for p in pos])
        self.agent_speed = np.array([v for _, _, v in starts])

    def _position(self, lane, s):
        """``lane.position(s, 0)`` of a straight lane (host, float64)."""
        i = self.road.lane(*lane)
        col = self.road.lanes.np_col
        return (col("start_x")[i] + s * col("dir_x")[i], col("start_y")[i] + s * col("dir_y")[i])

    def default_params(self) -> MergeTaskParams:
        raise NotImplementedError  # built by make_merge from the config

    def initial_vehicles(self, key, params: MergeTaskParams):
        """``_make_vehicles`` with the draws from ``key``."""
        return self.place(self.draws(key), params)

    def draws(self, key) -> dict:
        """The random numbers of ``_make_vehicles`` for the three highway IDM vehicles: ``lane_id``
        (0 or 1), ``position`` (U(-5, 5) m) and ``speed`` (U(-1, 1) m/s) noise."""
        dtype = L.float_dtype()
        k_lane, k_pos, k_speed = jax.random.split(key, 3)
        n = len(TRAFFIC)
        return dict(lane_id=jax.random.randint(k_lane, (n,), 0, 2),
                    position=jax.random.uniform(k_pos, (n,), dtype, -5.0, 5.0),
                    speed=jax.random.uniform(k_speed, (n,), dtype, -1.0, 1.0))

    def place(self, draws: dict, params: MergeTaskParams) -> dict:
        """Per-slot initial values from the draws (``lane.position(s, 0)``, list order)."""
        dtype = L.float_dtype()
        base = np.array(TRAFFIC)
        s = jnp.asarray(base[:, 0], dtype) + jnp.asarray(draws["position"], dtype)
        v = jnp.asarray(base[:, 1], dtype) + jnp.asarray(draws["speed"], dtype)
        y = jnp.asarray(draws["lane_id"]).astype(dtype) * L.DEFAULT_WIDTH  # a->b lane i: y = 4 i, from x = 0
        mx, my = self._position(("j", "k", 0), MERGING[0])
        x = jnp.concatenate([jnp.asarray(self.agent_x, dtype), s, jnp.asarray([mx], dtype)])
        y = jnp.concatenate([jnp.asarray(self.agent_y, dtype), y, jnp.asarray([my], dtype)])
        speed = jnp.concatenate([jnp.asarray(self.agent_speed, dtype), v, jnp.asarray([MERGING[1]], dtype)])
        target = jnp.concatenate([speed[:-1], jnp.asarray([MERGING[2]], dtype)])
        pad = self.num_slots - self.num_vehicles
        fill = lambda a, val: jnp.concatenate([a, jnp.full((pad,), val, a.dtype)])
        return dict(x=fill(x, 0.0), y=fill(y, 0.0), heading=jnp.zeros(self.num_slots, dtype),
                    speed=fill(speed, 0.0), target_speed=fill(target, 0.0),
                    alive=jnp.arange(self.num_slots) < self.num_vehicles,
                    delta=jnp.full((self.num_slots,), params.idm.delta, dtype))

    def outcome(self, prev, state, action, params: MergeTaskParams):
        idx = np.asarray(self.controlled)
        dtype = state.x.dtype
        crashed = state.crashed[idx]
        col = crashed.astype(dtype)
        right_lane = jnp.asarray(self.road.lane_id)[state.lane[idx]].astype(dtype) / 1
        lo, hi = params.reward_speed_range
        high_speed = 0 + (state.speed[idx] - lo) * (1 - 0) / (hi - lo)
        lane_change = ((action == Veh.LANE_LEFT) | (action == Veh.LANE_RIGHT)).astype(dtype)
        on_merge = state.alive & (state.lane == self.merge_lane)
        ts = jnp.where(on_merge, state.target_speed, 1.0)
        merging = jnp.sum(jnp.where(on_merge, (ts - state.speed) / ts, 0.0))
        reward = (params.collision_reward * col + params.right_lane_reward * right_lane
                  + params.high_speed_reward * high_speed + params.lane_change_reward * lane_change
                  + params.merging_speed_reward * merging)
        lo_r = params.collision_reward + params.merging_speed_reward
        hi_r = params.high_speed_reward + params.right_lane_reward
        reward = 0 + (reward - lo_r) * (1 - 0) / (hi_r - lo_r)
        cost = (params.collision_cost * crashed).astype(dtype)
        terminated = crashed | (state.x[idx] > FINISH_X)
        info = {"rewards": {"collision_reward": col, "right_lane_reward": right_lane,
                            "high_speed_reward": high_speed, "lane_change_reward": lane_change,
                            "merging_speed_reward": jnp.broadcast_to(merging, col.shape)}}
        return reward.astype(dtype), cost, terminated, info


def make_merge(name: str = NAME, env_config: dict | None = None, **overrides) -> TrafficEnv:
    """``merge-v0`` from highway-env's config keys (``env_config`` and/or keywords).

    Keys: highway-env's ``MergeEnv`` config (``controlled_vehicles`` 1..9, the reward keys,
    ``observation``, ``action``, frequencies; rendering keys are ignored) plus ``num_slots``
    (>= controlled_vehicles + 4), ``collision_cost``, ``idm`` (an IDMParams or a dict of its
    fields) and ``duration`` (a time limit in seconds; default none, as highway-env). Unknown
    or non-applicable keys and bad values raise ``ValueError`` naming them and what is allowed.
    """
    cfg = dict(DEFAULTS)
    cfg["observation"] = {"type": "Kinematics"}
    cfg["action"] = {"type": "DiscreteMetaAction"}
    cfg.update(CV.config_given(name, cfg, OWN_KEYS, env_config, overrides, "merge-v1 is not implemented"))

    sim = CV.int_value(name, "simulation_frequency", cfg["simulation_frequency"], 1)
    pol = CV.int_value(name, "policy_frequency", cfg["policy_frequency"], 1, sim)
    k = CV.int_value(name, "controlled_vehicles", cfg["controlled_vehicles"], 1, MAX_AGENTS)
    total = k + NUM_TRAFFIC
    num_slots = CV.int_value(name, "num_slots", cfg.get("num_slots", total), total)
    obs_cfg = CV.observation_config(name, cfg["observation"])
    action = CV.meta_action_config(name, cfg["action"])
    rsr = CV.speed_range(name, cfg["reward_speed_range"])
    duration = cfg.get("duration")
    duration = np.inf if duration is None else CV.number_value(name, "duration", duration, positive=True)
    task = MergeTask(k, num_slots, sim, pol, obs_cfg)
    num = lambda key: CV.number_value(name, key, cfg[key])
    params = MergeTaskParams(
        duration=duration,
        collision_cost=CV.cost_value(name, "collision_cost", cfg.get("collision_cost", 5.0)),
        target_speeds=action.get("target_speeds", np.linspace(20, 30, 3)),
        idm=CV.idm_params(name, cfg.get("idm")),
        obstacles=np.array([[task.obstacle[0], task.obstacle[1], 0.0, OBSTACLE_SIZE, OBSTACLE_SIZE]]),
        collision_reward=num("collision_reward"), right_lane_reward=num("right_lane_reward"),
        high_speed_reward=num("high_speed_reward"), reward_speed_range=rsr,
        merging_speed_reward=num("merging_speed_reward"), lane_change_reward=num("lane_change_reward"),
    )
    if params.high_speed_reward + params.right_lane_reward == params.collision_reward + params.merging_speed_reward:
        raise ValueError(f"{name}: the reward is normalised from [collision_reward + merging_speed_reward, "
                         f"high_speed_reward + right_lane_reward], which must differ")
    return TrafficEnv(task, params)
