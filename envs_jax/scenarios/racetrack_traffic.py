"""``racetrack-v0`` (highway-env ``envs/racetrack_env.py``, ``RacetrackEnv``) with K controlled vehicles.

Road: the two-lane circuit of ``RacetrackEnv._make_road`` (nine sections a->b->...->i->a,
5 m lanes, speed limit 10 m/s; :func:`envs_jax.scenarios.racetrack.build_road`).
Vehicles, in list order (``_make_vehicles``):

1. K controlled plain vehicles (continuous actions): the first on lane ``(a, b, U{0, 1})``,
   the others on a random lane (``random_lane_index``: a uniform start node, then a uniform
   lane id), each ``U(20, 50)`` m along its lane, heading along it, at the lane's speed
   limit (10 m/s). Several may overlap, as in highway-env.
2. With ``other_vehicles >= 1``: an IDM vehicle on ``(b, c, id)``, ``id`` the lane id of the
   *last* controlled vehicle, ``U(0, length of (b, c, 0))`` m along it, at ``6 + U(0, 3)`` m/s;
3. then ``U{0, other_vehicles - 1}`` further IDM candidates on random lanes (``U(0, lane
   length)`` m along, ``6 + U(0, 3)`` m/s), each kept only if it is at least 20 m from every
   vehicle placed before it.

IDM drivers keep highway-env's class constants (no ``randomize_behavior``). Slots:
``K + other_vehicles`` (rejected or undrawn candidates stay empty).

Reward of agent k (``RacetrackEnv._reward`` with vehicle k and its own action ``a_k``):
``lmap(w_c / (1 + c lat^2) + w_a |a_k| + w_x crashed + w_o on_road, [w_x, 1], [0, 1]) * on_road``,
``lat`` the lateral offset on the closest lane. Cost
``collision_cost * crashed + offroad_cost * off_road`` (the authors' racetrack cost). Agent k
terminates on a crash, or off the road with ``terminate_off_road``. The time limit
truncates after highway-env's clock (``time += 1 / policy_frequency`` in float64) reaches
``duration``; the step count is computed once from the configured duration, which is
therefore static. Default observation: an occupancy grid (``OccupancyGrid``, presence and
on-road layers, 12 x 12 cells of 3 m aligned with the observer); Kinematics configs are
accepted too.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import kinematic_obs, occupancy_grid
from envs_jax import lanes as L
from envs_jax.continuous_traffic_env import ContinuousTrafficEnv
from envs_jax.scenarios.config_values import (
    config_given,
    continuous_action_config,
    cost_value,
    flag_value,
    idm_params,
    int_value,
    number_value,
    unwrap_section,
)
from envs_jax.scenarios.racetrack import build_road
from envs_jax.traffic_env import Task, TrafficParams

NAME = "racetrack-v0"
MIN_SEPARATION = 20.0  # other vehicles closer than this to a placed vehicle are dropped [m]


@struct.dataclass
class RacetrackTrafficParams(TrafficParams):
    collision_reward: float = -1.0  # also the lower end of the reward normalisation
    lane_centering_cost: float = 4.0
    lane_centering_reward: float = 1.0
    action_reward: float = -0.3  # times |a_k|
    on_road_reward: float = 0.0  # highway-env's config.get("on_road_reward", 0)
    terminate_off_road: bool = True
    offroad_cost: float = 0.5
    acceleration_range: Any = (-5.0, 5.0)
    steering_range: Any = (-np.pi / 4, np.pi / 4)


# highway-env's RacetrackEnv.default_config (the keys that shape the program are static)
DEFAULTS = dict(
    observation={"type": "OccupancyGrid", "features": ["presence", "on_road"], "grid_size": [[-18, 18], [-18, 18]],
                 "grid_step": [3, 3], "as_image": False, "align_to_vehicle_axes": True},
    action={"type": "ContinuousAction", "longitudinal": False, "lateral": True, "target_speeds": [0, 5, 10]},
    simulation_frequency=15, policy_frequency=5, duration=300, collision_reward=-1, lane_centering_cost=4,
    lane_centering_reward=1, action_reward=-0.3, controlled_vehicles=1, other_vehicles=1, speed_limit=10.0,
    terminate_off_road=True,
)
OWN_KEYS = ("num_slots", "collision_cost", "offroad_cost", "idm", "on_road_reward")
# read by highway-env's config but not by RacetrackEnv (its lanes fix the speed limit at 10 m/s)
INERT_KEYS = ("speed_limit",)


def clock_steps(duration: float, policy_frequency: int) -> int:
    """Steps until highway-env's clock ``time += 1 / policy_frequency`` (float64) reaches ``duration``."""
    t, n, dt = 0.0, 0, 1 / policy_frequency
    while t < duration:
        t += dt
        n += 1
    return n


class RacetrackTraffic(Task):
    """The racetrack task for a given static layout."""

    route_length = 1

    def __init__(self, controlled_vehicles: int, other_vehicles: int, num_slots: int, simulation_frequency: int,
                 policy_frequency: int, max_steps: int, obs_config, longitudinal: bool, lateral: bool):
        self.name = NAME
        self.road = build_road()
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.max_steps = max_steps
        self.obs_config = obs_config
        self.longitudinal, self.lateral = longitudinal, lateral
        self.k = controlled_vehicles
        self.other_vehicles = other_vehicles
        self.num_vehicles = controlled_vehicles + other_vehicles  # most vehicles a reset can place
        self.num_slots = num_slots
        self.controlled = tuple(range(controlled_vehicles))
        self.n_roads = len(self.road.roads)

    def default_params(self):
        raise NotImplementedError  # built by make_racetrack from the config

    def initial_vehicles(self, key, params):
        """``_make_vehicles`` with the draws from ``key``."""
        return self.place(self.draws(key, params), params)

    def draws(self, key, params) -> dict:
        """The random numbers of ``_make_vehicles``: ``road [n]``, ``lane_id [n]``, ``frac [n]`` (position
        along the lane as a fraction of the drawn range), ``speed_u [n]`` (IDM vehicles: speed - 6 m/s) for the K agents
        then the ``other_vehicles`` IDM candidates (the front vehicle first), and ``extra`` (how many of
        the further candidates are drawn)."""
        dtype = L.float_dtype()
        n = self.num_vehicles
        k_road, k_id, k_frac, k_speed, k_extra = jax.random.split(key, 5)
        road = jax.random.randint(k_road, (n,), 0, self.n_roads).at[0].set(0)
        lane_id = jax.random.randint(k_id, (n,), 0, 2)
        frac = jax.random.uniform(k_frac, (n,), dtype)
        speed_u = jax.random.uniform(k_speed, (n,), dtype, 0.0, 3.0)
        extra = jax.random.randint(k_extra, (), 0, max(self.other_vehicles, 1))
        return dict(road=road, lane_id=lane_id, frac=frac, speed_u=speed_u, extra=extra)

    def place(self, draws: dict, params) -> dict:
        """Initial slots from the draws (``make_on_lane``'s arithmetic, the 20 m rejection rule in list order)."""
        dtype = L.float_dtype()
        lanes = self.road.lanes
        k, n = self.k, self.num_vehicles
        road_lanes = jnp.asarray(self.road.road_lanes)
        road = jnp.asarray(draws["road"], jnp.int32)
        lane_id = jnp.asarray(draws["lane_id"], jnp.int32)
        frac = jnp.asarray(draws["frac"], dtype)
        is_agent = jnp.arange(n) < k
        if self.other_vehicles:  # the front vehicle: (b, c) with the last agent's lane id
            front = k
            road = road.at[front].set(self.road.road_index[("b", "c")])
            lane_id = lane_id.at[front].set(lane_id[k - 1])
        lane = road_lanes[road, lane_id]
        length = lanes.col("length")[lane]
        bc_length = lanes.col("length")[self.road.lane("b", "c", 0)]
        # agents U(20, 50); front vehicle U(0, length of (b, c, 0)); others U(0, own lane length)
        s = jnp.where(is_agent, 20.0 + 30.0 * frac, frac * length)
        if self.other_vehicles:
            s = s.at[k].set(frac[k] * bc_length)
        x, y = L.position(lanes, lane, s, jnp.zeros_like(s))
        heading = L.heading_at(lanes, lane, s)
        speed = jnp.where(is_agent, lanes.col("speed_limit")[lane], 6.0 + jnp.asarray(draws["speed_u"], dtype))
        alive = jnp.ones(n, bool)
        if self.other_vehicles > 1:
            drawn = jnp.arange(n) < k + 1 + jnp.asarray(draws["extra"])

            def admit(alive, j):
                near = jnp.sqrt((x - x[j]) ** 2 + (y - y[j]) ** 2) < MIN_SEPARATION
                keep = drawn[j] & ~jnp.any(near & alive & (jnp.arange(n) < j))
                return alive.at[j].set(keep), None

            alive, _ = jax.lax.scan(admit, alive, jnp.arange(k + 1, n))
        pad = self.num_slots - n
        fill = lambda a, v: jnp.concatenate([a, jnp.full((pad,), v, a.dtype)])
        return dict(x=fill(x, 0.0), y=fill(y, 0.0), heading=fill(heading, 0.0), speed=fill(speed, 0.0),
                    alive=fill(alive, False), delta=jnp.full(self.num_slots, params.idm.delta, dtype))

    def outcome(self, prev, state, action, params: RacetrackTrafficParams):
        idx = np.asarray(self.controlled)
        dtype = state.x.dtype
        crashed = state.crashed[idx]
        on_road = state.on_road[idx]
        _, lat = L.local_coordinates(self.road.lanes, state.lane[idx], state.x[idx], state.y[idx])
        a = jnp.asarray(action, dtype)
        a_norm = jnp.sqrt(jnp.sum(a * a, axis=-1))
        col, onr = crashed.astype(dtype), on_road.astype(dtype)
        centering = 1 / (1 + params.lane_centering_cost * lat ** 2)
        raw = (params.lane_centering_reward * centering + params.action_reward * a_norm
               + params.collision_reward * col + params.on_road_reward * onr)
        lo = params.collision_reward
        reward = (0 + (raw - lo) * (1 - 0) / (1 - lo)) * onr
        cost = params.collision_cost * col + params.offroad_cost * (1 - onr)
        terminated = crashed | (params.terminate_off_road & ~on_road)
        info = {"rewards": {"lane_centering_reward": centering, "action_reward": a_norm,
                            "collision_reward": col, "on_road_reward": onr}}
        return reward.astype(dtype), cost.astype(dtype), terminated, info


# ----------------------------------------------------------------------------------------------
# Configuration: highway-env's config dict and keyword overrides -> an environment

def _action(value) -> tuple:
    return continuous_action_config(NAME, value, False, [0, 5, 10])


def _observation(value):
    obs = unwrap_section(NAME, "observation", value, "MultiAgentObservation", "observation_config")
    kind = obs.get("type")
    if kind == "OccupancyGrid":
        return occupancy_grid.OccupancyGridConfig.from_config(obs, where=f"{NAME}: observation")
    if kind == "Kinematics":
        return kinematic_obs.KinematicsConfig.from_config(obs, where=f"{NAME}: observation")
    raise ValueError(f"{NAME}: observation type must be 'OccupancyGrid' or 'Kinematics' (or MultiAgentObservation "
                     f"of one), got {kind!r}")


def make_racetrack(name: str = NAME, env_config: dict | None = None, **overrides) -> ContinuousTrafficEnv:
    """``racetrack-v0`` from highway-env's config keys (``env_config`` and/or keywords).

    Keywords are highway-env config keys (``controlled_vehicles=3``, ``other_vehicles``, ``duration``,
    ``observation``, ``action``, the reward keys, ``terminate_off_road``, ...) plus ``num_slots``
    (vehicle slots, >= controlled_vehicles + other_vehicles; the extra ones stay empty),
    ``collision_cost``, ``offroad_cost`` and ``idm`` (an :class:`~envs_jax.idm.IDMParams` or a dict
    of its fields). Unknown keys or bad values raise ``ValueError`` naming them and what is allowed.
    """
    cfg = dict(DEFAULTS)
    given = config_given(name, cfg, OWN_KEYS, env_config, overrides,
                         "racetrack-v1 is not implemented; racetrack-v0 searches neighbours on one lane segment "
                         "(False)")
    for key in INERT_KEYS:
        if key in given:
            number_value(name, key, given.pop(key), positive=True)
    cfg.update(given)

    sim = int_value(name, "simulation_frequency", cfg["simulation_frequency"], 1)
    pol = int_value(name, "policy_frequency", cfg["policy_frequency"], 1, sim)
    k = int_value(name, "controlled_vehicles", cfg["controlled_vehicles"], 1)
    others = int_value(name, "other_vehicles", cfg["other_vehicles"], 0)
    total = k + others
    num_slots = int_value(name, "num_slots", cfg.get("num_slots", total), total)
    duration = number_value(name, "duration", cfg["duration"], positive=True)
    obs_cfg = _observation(cfg["observation"])
    lon, lat, action = _action(cfg["action"])
    flag_value(name, "terminate_off_road", cfg["terminate_off_road"])
    idm = idm_params(name, cfg.get("idm"))
    collision_reward = number_value(name, "collision_reward", cfg["collision_reward"])
    if collision_reward == 1.0:
        raise ValueError(f"{name}: collision_reward must differ from 1 (the reward is normalised over "
                         f"[collision_reward, 1])")
    costs = {key: cost_value(name, key, cfg.get(key, default)) for key, default in
             (("collision_cost", 1.0), ("offroad_cost", 0.5))}
    task = RacetrackTraffic(k, others, num_slots, sim, pol, clock_steps(duration, pol), obs_cfg, lon, lat)
    params = RacetrackTrafficParams(
        duration=duration, target_speeds=action["target_speeds"], idm=idm, obstacles=None,
        collision_reward=collision_reward,
        lane_centering_cost=cost_value(name, "lane_centering_cost", cfg["lane_centering_cost"]),
        lane_centering_reward=number_value(name, "lane_centering_reward", cfg["lane_centering_reward"]),
        action_reward=number_value(name, "action_reward", cfg["action_reward"]),
        on_road_reward=number_value(name, "on_road_reward", cfg.get("on_road_reward", 0.0)),
        terminate_off_road=bool(cfg["terminate_off_road"]),
        acceleration_range=action["acceleration_range"], steering_range=action["steering_range"],
        **costs)
    return ContinuousTrafficEnv(task, params)
