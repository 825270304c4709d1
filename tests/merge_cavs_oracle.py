"""highway-env oracle of ``merge-cavs-v0``: MARL_CAVs' road and reward written with highway-env's own classes.

:class:`MergeCavsOracle` is highway-env's ``MergeEnv`` with MARL_CAVs' ``_make_road`` (built from highway-env's
``StraightLane`` / ``SineLane`` / ``Obstacle``), its 5 Hz decisions, 20 s, the target speeds 10..30 m/s, and its
per-agent ``_agent_reward`` and ``_is_terminal`` transcribed in numpy on highway-env's ``road.vehicles`` and
``RoadNetwork.next_lane``. Vehicles are injected by :func:`tests.traffic_oracle.inject`; :func:`cavs_drivers`
gives highway-env's ``IDMVehicle`` MARL_CAVs' two MOBIL constants for the duration of a run.

highway-env is imported here only (tests/).
"""

from __future__ import annotations

import contextlib

import numpy as np
from highway_env import utils
from highway_env.envs.merge_env import MergeEnv
from highway_env.road.lane import LineType, SineLane, StraightLane
from highway_env.road.road import Road, RoadNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.objects import Obstacle

ENDS = [220, 100, 100, 100]
SPEED_LIMIT = 40.0  # above every target speed: the IDM target is never clipped (MARL_CAVs' drivers do not clip)
CONFIG = {"COLLISION_REWARD": 200, "HIGH_SPEED_REWARD": 1, "HEADWAY_COST": 4, "HEADWAY_TIME": 1.2,
          "MERGING_LANE_COST": 4, "reward_speed_range": [10, 30]}


@contextlib.contextmanager
def cavs_drivers():
    """highway-env's IDMVehicle with MARL_CAVs' LANE_CHANGE_MIN_ACC_GAIN and LANE_CHANGE_MAX_BRAKING_IMPOSED."""
    old = IDMVehicle.LANE_CHANGE_MIN_ACC_GAIN, IDMVehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED
    IDMVehicle.LANE_CHANGE_MIN_ACC_GAIN, IDMVehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED = 0.1, 9.0
    try:
        yield
    finally:
        IDMVehicle.LANE_CHANGE_MIN_ACC_GAIN, IDMVehicle.LANE_CHANGE_MAX_BRAKING_IMPOSED = old


class MergeCavsOracle(MergeEnv):
    @classmethod
    def default_config(cls) -> dict:
        cfg = super().default_config()
        cfg.update(CONFIG)
        # MARL_CAVs' KinematicObservation defaults: see_behind, no clip, its ranges; road.vehicles only
        obs = {"type": "Kinematics", "see_behind": True, "clip": False, "include_obstacles": False,
               "features_range": {"x": [-150, 150], "y": [-12, 12], "vx": [-45, 45], "vy": [-45, 45]}}
        cfg.update({"policy_frequency": 5, "duration": 20, "observation": obs,
                    "action": {"type": "DiscreteMetaAction", "target_speeds": [10, 15, 20, 25, 30]}})
        return cfg

    def _make_road(self) -> None:
        net = RoadNetwork()
        c, s, n = LineType.CONTINUOUS_LINE, LineType.STRIPED, LineType.NONE
        e = ENDS
        lim = {"speed_limit": SPEED_LIMIT}
        net.add_lane("a", "b", StraightLane([0, 0], [sum(e[:2]), 0], line_types=[c, c], **lim))
        net.add_lane("b", "c", StraightLane([sum(e[:2]), 0], [sum(e[:3]), 0], line_types=[c, s], **lim))
        net.add_lane("c", "d", StraightLane([sum(e[:3]), 0], [sum(e), 0], line_types=[c, c], **lim))
        amplitude = 3.25
        ljk = StraightLane([0, 6.5 + 4], [e[0], 6.5 + 4], line_types=[c, c], forbidden=True, **lim)
        lkb = SineLane(ljk.position(e[0], -amplitude), ljk.position(sum(e[:2]), -amplitude), amplitude,
                       2 * np.pi / (2 * e[1]), np.pi / 2, line_types=[c, c], forbidden=True, **lim)
        lbc = StraightLane(lkb.position(e[1], 0), lkb.position(e[1], 0) + [e[2], 0], line_types=[n, c],
                           forbidden=True, **lim)
        net.add_lane("j", "k", ljk)
        net.add_lane("k", "b", lkb)
        net.add_lane("b", "c", lbc)
        road = Road(network=net, np_random=self.np_random, record_history=self.config["show_trajectories"])
        road.objects.append(Obstacle(road, lbc.position(e[2], 0)))
        self.road = road

    def _make_vehicles(self) -> None:
        ego = self.action_type.vehicle_class(self.road, self.road.network.get_lane(("a", "b", 0)).position(30, 0),
                                             speed=25)
        self.road.vehicles.append(ego)
        self.vehicle = ego

    def _headway(self, vehicle) -> float:
        """MARL_CAVs' ``_compute_headway_distance``."""
        headway = 60
        for v in self.road.vehicles:
            if v.lane_index == vehicle.lane_index and v.position[0] > vehicle.position[0]:
                headway = min(headway, v.position[0] - vehicle.position[0])
            if (vehicle.lane_index != ("b", "c", 1)
                    and v.lane_index == self.road.network.next_lane(vehicle.lane_index, position=vehicle.position)
                    and v.position[0] > vehicle.position[0]):
                headway = min(headway, v.position[0] - vehicle.position[0])
        return headway

    def _rewards(self, action) -> dict:
        vehicle = self.vehicle
        scaled_speed = utils.lmap(vehicle.speed, self.config["reward_speed_range"], [0, 1])
        if vehicle.lane_index == ("b", "c", 1):
            merging = -np.exp(-(vehicle.position[0] - sum(ENDS[:3])) ** 2 / (10 * ENDS[2]))
        else:
            merging = 0
        headway = self._headway(vehicle)
        headway_cost = np.log(headway / (self.config["HEADWAY_TIME"] * vehicle.speed)) if vehicle.speed > 0 else 0
        return {"collision": float(vehicle.crashed), "speed": float(np.clip(scaled_speed, 0, 1)),
                "merging": merging, "headway": headway_cost}

    def _reward(self, action) -> float:
        r = self._rewards(action)
        return (self.config["COLLISION_REWARD"] * (-1 * r["collision"])
                + self.config["HIGH_SPEED_REWARD"] * r["speed"]
                + self.config["MERGING_LANE_COST"] * r["merging"]
                + self.config["HEADWAY_COST"] * (min(0, r["headway"])))

    def _is_terminated(self) -> bool:
        return any(v.crashed for v in self.controlled_vehicles)

    def _is_truncated(self) -> bool:
        return False
