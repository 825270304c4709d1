"""highway-env oracle of the four two-agent scenarios of Safe-MARL-in-Autonomous-Driving.

This module is the *reference* the JAX simulator (``envs_jax``) is compared against.  It rebuilds the
authors' scenarios (their fork of highway-env v1.7.1, described in
``docs/scenarios.md``) on top of the installed highway-env 1.12.1, by subclassing
highway-env's own environment classes and replacing only

* ``_make_vehicles``: the two controlled vehicles exactly as the authors place them, no other traffic;
* ``step``: the authors' multi-agent step (per-agent reward, cost, termination and arrival bookkeeping),
  evaluated in their order: ``time += 1/policy_freq``; ``_simulate``; ``observe``; ``terminated``
  (before the rewards); rewards leader first; cost.

highway-env's own ``_make_road`` is kept for all four scenarios: it is line-for-line the fork's road
(checked against the fork's source and against the lane tables of docs/scenarios.md, see ``tests/test_oracle.py``).
The only core difference between v1.7.1 and 1.12.1 that matters here is neutralised through the
observation config (``include_obstacles: False``, docs/parity.md).

highway-env is imported here only; it must never be imported outside ``tests/``.

Public API (used by the JAX parity tests):

* :func:`make_oracle_env` -- the configured highway-env env of a scenario;
* :func:`oracle_lanes`   -- the lanes in ``road.network.graph`` iteration order (global lane numbering);
* :func:`run_oracle`     -- one episode under given actions, with per-step and per-substep records.
"""

from __future__ import annotations

import functools

import numpy as np
from highway_env import utils
from highway_env.envs.intersection_env import ContinuousIntersectionEnv
from highway_env.envs.merge_env import MergeEnv
from highway_env.envs.racetrack_env import RacetrackEnv
from highway_env.envs.roundabout_env import RoundaboutEnv

SCENARIOS = ("merge", "roundabout", "intersection", "racetrack")
DISCRETE = {"merge": True, "roundabout": True, "intersection": False, "racetrack": False}

# Default longitudinal start offset of both intersection agents (the fork draws 60 + N(1, 1)).
INTERSECTION_DEFAULT_S = 61.0

# Observation config shared by every experiment (docs/scenarios.md, observation).  ``flatten`` of the authors'
# env_config.json is not a v1.7.1 (nor 1.12.1) option and is left out.  ``include_obstacles: False``
# reproduces v1.7.1, which never observed ``road.objects`` (docs/parity.md).
_OBSERVATION = {
    "type": "MultiAgentObservation",
    "observation_config": {
        "type": "Kinematics",
        "features": ["x", "y", "vx", "vy"],
        "vehicles_count": 2,
        "absolute": True,
        "normalize": False,
        "see_behind": True,
        "include_obstacles": False,
    },
}


def _multi_action(action_config: dict) -> dict:
    return {"type": "MultiAgentAction", "action_config": action_config}


# The authors' env_config.json files, resolved on top of each env's default config (docs/scenarios.md).
# ``configure`` does a shallow update, so "observation" and "action"
# replace the env defaults wholesale, as in the fork.
CONFIGS = {
    "merge": {
        "simulation_frequency": 15,
        "policy_frequency": 1,
        "duration": 20,
        "observation": _OBSERVATION,
        # The authors' config gives no target_speeds, i.e. MDPVehicle.DEFAULT_TARGET_SPEEDS
        # = linspace(20, 30, 3); the same float values are spelled out here.
        "action": _multi_action({"type": "DiscreteMetaAction", "target_speeds": [20.0, 25.0, 30.0]}),
    },
    "roundabout": {
        "simulation_frequency": 15,
        "policy_frequency": 1,
        "duration": 20,
        "observation": _OBSERVATION,
        "action": _multi_action({"type": "DiscreteMetaAction", "target_speeds": [0, 4, 8, 12, 16]}),
    },
    "intersection": {
        "simulation_frequency": 15,
        "policy_frequency": 1,
        "duration": 20,
        "controlled_vehicles": 2,
        "initial_vehicle_count": 0,
        "spawn_probability": 0,
        "destination": "o1",
        "offroad_terminal": True,
        "observation": _OBSERVATION,
        # dynamical defaults to False: plain kinematic Vehicle, steering 0, a in [-1,1] -> [-5,5] m/s^2.
        "action": _multi_action({"type": "ContinuousAction", "longitudinal": True, "lateral": False}),
        # Keys of the authors' env_config that the multi-agent step never reads (kept for fidelity).
        "arrived_reward": 10,
        "collision_reward": -10,
        "high_speed_reward": 0,
        "on_road_reward": 0,
        "first_arrive_reward": 20,
        "second_arrive_reward": 10,
        # Start offsets of the two agents along their approach lanes (None -> 61.0, "random" ->
        # 60 + N(1, 1) from env.np_random as the fork does).  Not a highway-env key.
        "leader_s": None,
        "follower_s": None,
    },
    "racetrack": {
        "simulation_frequency": 15,
        "policy_frequency": 5,
        "duration": 40,
        "controlled_vehicles": 2,
        "observation": _OBSERVATION,
        # steering in [-1,1] -> [-pi/4, pi/4], acceleration 0; "target_speeds" is swallowed by **kwargs.
        "action": _multi_action(
            {"type": "ContinuousAction", "longitudinal": False, "lateral": True, "target_speeds": [0, 5, 10]}
        ),
    },
}


# --------------------------------------------------------------------------------------------------
# The authors' multi-agent step, shared by the four scenarios
# --------------------------------------------------------------------------------------------------


class _TwoAgentMixin:
    """Multi-agent step of the fork (e.g. merge_env.py:120-162).  Leader = controlled_vehicles[0]."""

    def _reset(self) -> None:
        self.leader_arrived = False
        self.follower_arrived = False
        self.first_arrived = 0
        self._make_road()
        self._make_vehicles()

    def _info(self, obs, action=None) -> dict:
        # Abstract v1.7.1 keys; the upstream ``_rewards`` of 1.12.1 differ from v1.7.1 and are not
        # used by the authors' step, so "rewards" is left out.
        return {"speed": self.vehicle.speed, "crashed": self.vehicle.crashed, "action": action}

    def _after_observe(self) -> None:
        """Hook between observation and termination (intersection: ``_clear_vehicles``)."""

    def step(self, action):
        if self.road is None or self.vehicle is None:
            raise NotImplementedError("The road and vehicle must be initialized in the environment implementation")
        self.time += 1 / self.config["policy_frequency"]
        self._simulate(action)
        obs = self.observation_type.observe()
        truncated = self._is_truncated()
        self._after_observe()
        leader, follower = self.controlled_vehicles[0], self.controlled_vehicles[1]
        terminated = [self.leader_is_terminal(leader), self.follower_is_terminal(follower)]
        reward = [self.leader_agent_reward(leader, action[0]), self.follower_agent_reward(follower, action[1])]
        info = self._two_agent_info(obs, action)
        info["cost"] = np.array([self._cost(leader), self._cost(follower)])
        return obs, reward, terminated, truncated, info

    def _cost(self, vehicle) -> float:
        return 5.0 * vehicle.crashed


class OracleMergeEnv(_TwoAgentMixin, MergeEnv):
    """merge-v0 of the fork (docs/scenarios.md, merge)."""

    def _make_vehicles(self) -> None:
        self.controlled_vehicles = []
        road = self.road
        leader = self.action_type.vehicle_class(road, road.network.get_lane(("a", "b", 1)).position(70, 0), speed=25)
        road.vehicles.append(leader)
        self.controlled_vehicles.append(leader)
        follower = self.action_type.vehicle_class(road, road.network.get_lane(("j", "k", 0)).position(70, 0), speed=25)
        road.vehicles.append(follower)
        self.controlled_vehicles.append(follower)

    def _is_truncated(self) -> bool:
        return False

    def _is_terminal(self, vehicle) -> bool:
        return vehicle.crashed or bool(vehicle.position[0] > 350) or self.time >= self.config["duration"]

    leader_is_terminal = follower_is_terminal = _is_terminal

    @staticmethod
    def _base_reward(vehicle) -> float:
        reward = 0
        if vehicle.speed_index / (vehicle.target_speeds.size - 1):  # +2 iff target-speed index >= 1
            reward += 2
        if vehicle.crashed:
            reward -= 5
        return reward

    def leader_agent_reward(self, vehicle, action) -> float:
        reward = self._base_reward(vehicle)
        if vehicle.position[0] > 350:
            if not self.leader_arrived and not self.follower_arrived:
                reward += 10
                self.first_arrived = 1
            elif not self.leader_arrived and self.follower_arrived:
                reward += 5
            self.leader_arrived = True
        return reward

    def follower_agent_reward(self, vehicle, action) -> float:
        reward = self._base_reward(vehicle)
        if vehicle.position[0] > 350:
            if not self.leader_arrived and not self.follower_arrived:
                reward += 10
                self.first_arrived = 2
            elif self.leader_arrived and not self.follower_arrived:
                reward += 5
            self.follower_arrived = True
        return reward

    def _two_agent_info(self, obs, action) -> dict:
        # The fork's merge info has no abstract keys; the arrival flags are zeroed on any crash.
        info = {"crash": self.controlled_vehicles[0].crashed or self.controlled_vehicles[1].crashed}
        if info["crash"]:
            info["leader_arrived"] = 0
            info["follower_arrived"] = 0
        else:
            info["leader_arrived"] = self.leader_arrived
            info["follower_arrived"] = self.follower_arrived
        return info


class OracleRoundaboutEnv(_TwoAgentMixin, RoundaboutEnv):
    """roundabout-v0 of the fork (docs/scenarios.md, roundabout)."""

    def _make_vehicles(self) -> None:
        self.controlled_vehicles = []
        # The south car (the fork's ``ego_vehicle``, the FOLLOWER) is appended to road.vehicles first.
        lane_s = self.road.network.get_lane(("ser", "ses", 0))
        follower = self.action_type.vehicle_class(
            self.road, lane_s.position(85, 0), speed=8, heading=lane_s.heading_at(140)
        )
        try:
            follower.plan_route_to("nxs")
        except AttributeError:
            pass
        self.road.vehicles.append(follower)
        # The west car (``ego_vehicle_2``) is the LEADER.
        lane_w = self.road.network.get_lane(("wer", "wes", 0))
        leader = self.action_type.vehicle_class(
            self.road, lane_w.position(125, 0), speed=8, heading=lane_w.heading_at(140)
        )
        try:
            leader.plan_route_to("nxs")
        except AttributeError:
            pass
        self.road.vehicles.append(leader)
        self.controlled_vehicles.append(leader)
        self.controlled_vehicles.append(follower)

    def _is_truncated(self) -> bool:
        return False

    def has_arrived_target(self, vehicle, exit_distance: float = 20) -> bool:
        return (
            "nxs" in vehicle.lane_index[0]
            and "nxr" in vehicle.lane_index[1]
            and vehicle.lane.local_coordinates(vehicle.position)[0] >= exit_distance
        )

    def _is_terminal(self, vehicle) -> bool:
        return vehicle.crashed or self.has_arrived_target(vehicle) or self.time >= self.config["duration"]

    leader_is_terminal = follower_is_terminal = _is_terminal

    def _agent_reward(self, vehicle, action=None) -> float:
        reward = 0
        if vehicle.crashed:
            reward -= 5
        if vehicle.speed >= 10 and vehicle.speed <= 15:
            reward += 2
        if self.has_arrived_target(vehicle):
            reward += 5
        return reward

    leader_agent_reward = follower_agent_reward = _agent_reward

    def _two_agent_info(self, obs, action) -> dict:
        info = self._info(obs, action)
        info["leader_arrived"] = self.has_arrived_target(self.controlled_vehicles[0])
        info["follower_arrived"] = self.has_arrived_target(self.controlled_vehicles[1])
        info["crash"] = self.controlled_vehicles[0].crashed or self.controlled_vehicles[1].crashed
        return info


class OracleIntersectionEnv(_TwoAgentMixin, ContinuousIntersectionEnv):
    """intersection-v1 (ContinuousIntersectionEnv) of the fork (docs/scenarios.md, intersection)."""

    def _make_vehicles(self, n_vehicles: int = 0) -> None:
        # The fork also sets IDMVehicle.DISTANCE_WANTED/COMFORT_ACC_* (class attributes, process-wide)
        # and spawns n_vehicles - 1 = -1 (i.e. no) random cars; both are irrelevant and skipped.
        # The 3 s pre-simulation of the empty road is kept: it only advances RegulatedRoad.steps.
        for _ in range(3 * self.config["simulation_frequency"]):
            self.road.act()
            self.road.step(1 / self.config["simulation_frequency"])
        self.controlled_vehicles = []
        offsets = (self.config.get("leader_s"), self.config.get("follower_s"))
        for ego_id in range(self.config["controlled_vehicles"]):
            ego_lane = self.road.network.get_lane((f"o{ego_id % 4}", f"ir{ego_id % 4}", 0))
            s = offsets[ego_id] if ego_id < 2 else None
            if s is None:
                s = INTERSECTION_DEFAULT_S
            elif isinstance(s, str) and s == "random":
                s = 60 + 1 * self.np_random.normal(1)  # the fork's draw, N(1, 1)
            ego_vehicle = self.action_type.vehicle_class(
                self.road, ego_lane.position(float(s), 0), speed=ego_lane.speed_limit, heading=ego_lane.heading_at(60)
            )
            # plan_route_to raises AttributeError on a plain Vehicle in the fork (swallowed): no route.
            self.road.vehicles.append(ego_vehicle)
            self.controlled_vehicles.append(ego_vehicle)

    def _reset(self) -> None:
        self.leader_arrived = False
        self.follower_arrived = False
        self.first_arrived = 0
        self._make_road()
        self._make_vehicles(self.config["initial_vehicle_count"])

    def _is_truncated(self):
        return None  # the fork's ``_is_truncated`` returns nothing

    def _after_observe(self) -> None:
        self._clear_vehicles()  # only ever removes non-controlled vehicles

    def has_arrived_target(self, vehicle, road_i: int, exit_distance: float = 5) -> bool:
        return (
            "il" + str(road_i) in vehicle.lane_index[0]
            and "o" + str(road_i) in vehicle.lane_index[1]
            and vehicle.lane.local_coordinates(vehicle.position)[0] >= exit_distance
        )

    def _is_terminal(self, vehicle, road_i: int) -> bool:
        return (
            vehicle.crashed
            or self.has_arrived_target(vehicle, road_i)
            or self.time >= self.config["duration"]
            or (self.config["offroad_terminal"] and not vehicle.on_road)
        )

    def leader_is_terminal(self, vehicle) -> bool:
        return self._is_terminal(vehicle, 2)

    def follower_is_terminal(self, vehicle) -> bool:
        return self._is_terminal(vehicle, 3)

    @staticmethod
    def _base_reward(vehicle) -> float:
        reward = 0
        if vehicle.crashed:
            reward -= 5
        if vehicle.speed >= 8 and vehicle.speed <= 12:
            reward += 2
        return reward

    def leader_agent_reward(self, vehicle, action=None) -> float:
        reward = self._base_reward(vehicle)
        if self.has_arrived_target(vehicle, 2):
            if not self.leader_arrived and not self.follower_arrived:
                reward += 5
                self.first_arrived = 1
            elif not self.leader_arrived and self.follower_arrived:
                reward += 2
            self.leader_arrived = True
        return reward

    def follower_agent_reward(self, vehicle, action=None) -> float:
        reward = self._base_reward(vehicle)
        if self.has_arrived_target(vehicle, 3):
            if not self.leader_arrived and not self.follower_arrived:
                reward += 5
                self.first_arrived = 2
            elif self.leader_arrived and not self.follower_arrived:
                reward += 2
            self.follower_arrived = True
        return reward

    def _two_agent_info(self, obs, action) -> dict:
        info = self._info(obs, action)
        info["first_arrived"] = self.first_arrived
        info["crashed"] = self.controlled_vehicles[0].crashed or self.controlled_vehicles[1].crashed
        return info


class OracleRacetrackEnv(_TwoAgentMixin, RacetrackEnv):
    """racetrack-v0 of the fork (docs/scenarios.md, racetrack)."""

    def _make_vehicles(self) -> None:
        self.controlled_vehicles = []
        for i in range(self.config["controlled_vehicles"]):
            vehicle = self.action_type.vehicle_class.make_on_lane(self.road, ("a", "b", i), speed=None, longitudinal=35)
            self.controlled_vehicles.append(vehicle)
            self.road.vehicles.append(vehicle)

    def _is_truncated(self) -> bool:
        return False

    def _is_terminal(self, vehicle) -> bool:
        return vehicle.crashed or (not vehicle.on_road) or self.time >= self.config["duration"]

    leader_is_terminal = follower_is_terminal = _is_terminal

    def _agent_reward(self, vehicle, action) -> float:
        _, lateral = vehicle.lane.local_coordinates(vehicle.position)
        rewards = {
            "lane_centering_reward": 1 / (1 + self.config["lane_centering_cost"] * lateral**2),
            "action_reward": np.linalg.norm(action),  # this agent's raw (unclipped) action
            "collision_reward": vehicle.crashed,
            "on_road_reward": vehicle.on_road,
        }
        reward = sum(self.config.get(name, 0) * r for name, r in rewards.items())
        reward = utils.lmap(reward, [self.config["collision_reward"], 1], [0, 1])
        reward *= rewards["on_road_reward"]
        return reward

    leader_agent_reward = follower_agent_reward = _agent_reward

    def _cost(self, vehicle) -> float:
        return vehicle.crashed + 0.5 * (not vehicle.on_road)

    def _two_agent_info(self, obs, action) -> dict:
        info = self._info(obs, action)
        info["crash"] = self.controlled_vehicles[0].crashed or self.controlled_vehicles[1].crashed
        return info


ENV_CLASSES = {
    "merge": OracleMergeEnv,
    "roundabout": OracleRoundaboutEnv,
    "intersection": OracleIntersectionEnv,
    "racetrack": OracleRacetrackEnv,
}


# --------------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------------


def make_oracle_env(scenario: str, leader_s=None, follower_s=None, config: dict | None = None):
    """The configured highway-env env of ``scenario`` (already reset once by its constructor).

    :param leader_s, follower_s: intersection only: start offset (m) of each agent along its approach
        lane (the fork draws ``60 + N(1, 1)``).  ``None`` gives the deterministic 61.0; ``"random"``
        draws as the fork does, from ``env.np_random``.
    :param config: extra config entries, applied on top of the authors' config.
    """
    if scenario not in ENV_CLASSES:
        raise ValueError(f"unknown scenario {scenario!r}, expected one of {SCENARIOS}")
    cfg = dict(CONFIGS[scenario])
    if scenario == "intersection":
        cfg["leader_s"] = leader_s
        cfg["follower_s"] = follower_s
    elif leader_s is not None or follower_s is not None:
        raise ValueError("leader_s / follower_s only apply to the intersection scenario")
    if config:
        cfg.update(config)
    return ENV_CLASSES[scenario](config=cfg)


def _lanes_of(network) -> list:
    return [
        (_from, _to, _id, lane)
        for _from, to_dict in network.graph.items()
        for _to, lanes in to_dict.items()
        for _id, lane in enumerate(lanes)
    ]


@functools.lru_cache(maxsize=None)
def _cached_lanes(scenario: str) -> tuple:
    return tuple(_lanes_of(make_oracle_env(scenario).road.network))


def oracle_lanes(scenario: str) -> list:
    """``(from, to, id, lane)`` for every lane, in the iteration order of ``road.network.graph``.

    This is the order ``get_closest_lane_index`` scans (``np.argmin`` takes the first minimum); the
    JAX simulator numbers its lanes globally by it.  The lane objects are shared (do not mutate).
    """
    return list(_cached_lanes(scenario))


def _to_env_actions(scenario: str, actions) -> list:
    """Per-step action tuples ``(a_leader, a_follower)`` as the authors' runner passes them."""
    a = np.asarray(actions)
    if DISCRETE[scenario]:
        if a.ndim != 2 or a.shape[1] != 2:
            raise ValueError(f"discrete actions must have shape [T, 2], got {a.shape}")
        return [(int(row[0]), int(row[1])) for row in a]
    if not np.issubdtype(a.dtype, np.floating):
        a = a.astype(np.float64)
    if a.ndim == 2 and a.shape[1] == 2:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[1] != 2 or a.shape[2] != 1:
        raise ValueError(f"continuous actions must have shape [T, 2] or [T, 2, 1], got {a.shape}")
    return [(row[0].copy(), row[1].copy()) for row in a]


def run_oracle(scenario: str, actions, seed: int | None = None, **kwargs) -> dict:
    """Run one episode of ``scenario`` under ``actions`` (leader first) in highway-env.

    The episode stops at the first step where ``np.all(terminated)`` (the authors' runner) or when the
    actions run out.  Continuous actions keep their floating dtype (ints are cast to float64); the
    authors' runner fed float32 network outputs, which makes ``lmap`` compute in float32.

    :param actions: int ``[T, 2]`` (discrete: 0 LANE_LEFT, 1 IDLE, 2 LANE_RIGHT, 3 FASTER, 4 SLOWER)
        or float ``[T, 2]`` / ``[T, 2, 1]`` (continuous).
    :param seed: passed to ``env.reset`` (only matters for intersection with ``"random"`` offsets).
    :param kwargs: forwarded to :func:`make_oracle_env` (``leader_s``, ``follower_s``, ``config``).
    :return: dict of numpy arrays, agent axis ordered (leader, follower); see the keys below.

    Per step t (0-based, the state after step t+1; arrays ``[T]``/``[T, 2]`` with T = ``length``):
    ``reward``, ``cost`` (float64), ``terminated`` (bool, as the env returns it, incl. the time limit),
    ``done`` (bool, ``np.all(terminated)``), ``crash`` (bool, either crashed), ``arrived`` (bool: the
    arrival flags of the info dict -- merge: the one-shot flags zeroed on any crash; roundabout:
    ``has_arrived_target`` now; intersection (no such info keys): the env's one-shot flags; racetrack:
    False), ``arrived_flag`` (bool, the env's one-shot flags, un-zeroed; roundabout: as ``arrived``),
    ``first_arrived`` (int, merge/intersection; else 0), ``time`` (float, ``env.time``).

    Per state, initial state first (``[T+1, 2]``): ``obs`` (``[T+1, 2, 8]`` float32, row i = agent i's
    ``[x, y, vx, vy]`` of itself then of the other vehicle, zeros if none within 200 m), ``x``, ``y``,
    ``heading``, ``speed``, ``crashed``, ``on_road`` (bool, ``vehicle.on_road``), ``lane`` (int, global
    number of ``vehicle.lane_index`` in :func:`oracle_lanes` order) and, for the discrete scenarios
    (MDPVehicle), ``target_lane`` (int), ``speed_index`` (int), ``target_speed`` (float).

    Per simulation substep (``[T*frames, 2]``, recorded right after every ``road.step(dt)``):
    ``sub_x``, ``sub_y``, ``sub_heading``, ``sub_speed``, ``sub_crashed``, ``sub_on_road``, ``sub_lane``,
    ``sub_steering``, ``sub_acceleration`` (the action the vehicle integrated in that substep, after
    ``clip_actions``) and, for MDP vehicles, ``sub_target_lane``.

    Scalars: ``length`` (steps run), ``frames`` (substeps per step), ``scenario``.
    """
    env = make_oracle_env(scenario, **kwargs)
    env_actions = _to_env_actions(scenario, actions)
    obs, _ = env.reset(seed=seed)
    lane_number = {(f, t, i): n for n, (f, t, i, _) in enumerate(_lanes_of(env.road.network))}
    discrete = DISCRETE[scenario]
    vehicles = env.controlled_vehicles[:2]
    frames = int(env.config["simulation_frequency"] // env.config["policy_frequency"])

    def lane_no(index) -> int:
        return lane_number[(index[0], index[1], int(index[2]))]

    states = {k: [] for k in ("x", "y", "heading", "speed", "crashed", "on_road", "lane")}
    if discrete:
        states.update(target_lane=[], speed_index=[], target_speed=[])
    subs = {k: [] for k in ("x", "y", "heading", "speed", "crashed", "on_road", "lane", "steering", "acceleration")}
    if discrete:
        subs["target_lane"] = []

    def record_state() -> None:
        states["x"].append([v.position[0] for v in vehicles])
        states["y"].append([v.position[1] for v in vehicles])
        states["heading"].append([v.heading for v in vehicles])
        states["speed"].append([v.speed for v in vehicles])
        states["crashed"].append([v.crashed for v in vehicles])
        states["on_road"].append([v.on_road for v in vehicles])
        states["lane"].append([lane_no(v.lane_index) for v in vehicles])
        if discrete:
            states["target_lane"].append([lane_no(v.target_lane_index) for v in vehicles])
            states["speed_index"].append([int(v.speed_index) for v in vehicles])
            states["target_speed"].append([float(v.target_speed) for v in vehicles])

    def record_sub() -> None:
        subs["x"].append([v.position[0] for v in vehicles])
        subs["y"].append([v.position[1] for v in vehicles])
        subs["heading"].append([v.heading for v in vehicles])
        subs["speed"].append([v.speed for v in vehicles])
        subs["crashed"].append([v.crashed for v in vehicles])
        subs["on_road"].append([v.on_road for v in vehicles])
        subs["lane"].append([lane_no(v.lane_index) for v in vehicles])
        subs["steering"].append([v.action["steering"] for v in vehicles])
        subs["acceleration"].append([v.action["acceleration"] for v in vehicles])
        if discrete:
            subs["target_lane"].append([lane_no(v.target_lane_index) for v in vehicles])

    road_step = env.road.step

    def recording_step(dt: float) -> None:
        road_step(dt)
        record_sub()

    env.road.step = recording_step  # instance attribute shadows the (Regulated)Road.step method

    obs_list = [np.asarray(obs, dtype=np.float32).reshape(2, 8)]
    record_state()
    out_steps = {k: [] for k in ("reward", "cost", "terminated", "done", "crash", "arrived", "arrived_flag",
                                 "first_arrived", "time")}
    for action in env_actions:
        obs, reward, terminated, _, info = env.step(action)
        obs_list.append(np.asarray(obs, dtype=np.float32).reshape(2, 8))
        record_state()
        crash = bool(vehicles[0].crashed or vehicles[1].crashed)
        if scenario in ("merge", "roundabout"):
            arrived = [bool(info["leader_arrived"]), bool(info["follower_arrived"])]
        elif scenario == "intersection":
            arrived = [bool(env.leader_arrived), bool(env.follower_arrived)]
        else:
            arrived = [False, False]
        if scenario == "roundabout":
            arrived_flag = list(arrived)
        else:
            arrived_flag = [bool(getattr(env, "leader_arrived", False)), bool(getattr(env, "follower_arrived", False))]
        out_steps["reward"].append([float(r) for r in reward])
        out_steps["cost"].append(np.asarray(info["cost"], dtype=np.float64))
        out_steps["terminated"].append([bool(t) for t in terminated])
        out_steps["done"].append(bool(np.all(terminated)))
        out_steps["crash"].append(crash)
        out_steps["arrived"].append(arrived)
        out_steps["arrived_flag"].append(arrived_flag)
        out_steps["first_arrived"].append(int(getattr(env, "first_arrived", 0)))
        out_steps["time"].append(float(env.time))
        if np.all(terminated):
            break
    env.road.step = road_step
    env.close()

    length = len(out_steps["reward"])
    result = {"scenario": scenario, "length": length, "frames": frames}
    result["obs"] = np.stack(obs_list).astype(np.float32)
    bool_keys = {"terminated", "done", "crash", "arrived", "arrived_flag", "crashed", "on_road"}
    int_keys = {"first_arrived", "lane", "target_lane", "speed_index"}

    def as_array(key, values, shape):
        dtype = bool if key in bool_keys else (np.int64 if key in int_keys else np.float64)
        return np.asarray(values, dtype=dtype).reshape(shape)

    for key, values in out_steps.items():
        per_agent = key in ("reward", "cost", "terminated", "arrived", "arrived_flag")
        result[key] = as_array(key, values, (length, 2) if per_agent else (length,))
    for key, values in states.items():
        result[key] = as_array(key, values, (length + 1, 2))
    for key, values in subs.items():
        result["sub_" + key] = as_array(key, values, (length * frames, 2))
    return result
