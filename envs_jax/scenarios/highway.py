"""``highway-v0`` and ``highway-fast-v0`` (highway-env ``envs/highway_env.py``) with K controlled vehicles.

Road: ``lanes_count`` straight lanes of 10 km (``RoadNetwork.straight_road_network``,
lane i at y = 4 i, speed limit 30 m/s). Vehicles, in list order: for each
controlled vehicle k, the vehicle itself (``create_random`` at 25 m/s, lane
``initial_lane_id`` or random, spacing ``ego_spacing``) followed by its share
``near_split(vehicles_count, K)[k]`` of IDM vehicles (``create_random``: random
lane, speed U(0.7, 0.8) x 30 m/s, spacing ``1 / vehicles_density``, then
``randomize_behavior``). Each new vehicle is placed ``offset * U(0.9, 1.1)`` ahead of
the furthest one so far, ``offset = spacing (12 + v) exp(-5/40 lanes_count)``.

Reward of agent k (highway-env's ``_reward`` evaluated for vehicle k): collision,
right-lane (target lane id / (lanes - 1)), high-speed (forward speed mapped from
``reward_speed_range`` to [0, 1], clipped) and on-road terms, normalised to [0, 1]
with ``normalize_reward``, times on-road. Cost ``collision_cost * crashed``. Agent k
terminates when crashed (or off-road with ``offroad_terminal``); the time limit
truncates. ``highway-fast-v0``: 5 Hz simulation, 3 lanes, 20 vehicles, 30 s,
``ego_spacing`` 1.5, and only the controlled vehicles check collisions.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import kinematic_obs, trig
from envs_jax import lanes as L
from envs_jax.road import RoadNetwork
from envs_jax.scenarios.config_values import (
    config_given,
    cost_value,
    flag_value,
    idm_params,
    int_value,
    meta_action_config,
    number_value,
    observation_config,
    speed_range,
)
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams

C, S, N = L.LINE_CONTINUOUS_LINE, L.LINE_STRIPED, L.LINE_NONE
LANE_LENGTH = 10000.0
CHUNK_SLOTS = 2048  # vehicle slots a batched step handles at once on the CPU
SPEED_LIMIT = 30.0
EGO_SPEED = 25.0


@struct.dataclass
class HighwayParams(TrafficParams):
    ego_spacing: float = 2.0
    vehicles_density: float = 1.0
    initial_lane_id: int = -1  # -1: random lane (highway-env's None)
    collision_reward: float = -1.0
    right_lane_reward: float = 0.1
    high_speed_reward: float = 0.4
    lane_change_reward: float = 0.0  # listed by highway-env, not a term of its reward
    on_road_reward: float = 0.0  # highway-env's config.get("on_road_reward", 0)
    reward_speed_range: Any = (20.0, 30.0)
    normalize_reward: bool = True
    offroad_terminal: bool = False


# highway-env's default configs (envs/highway_env.py); the keys that shape the program are static.
DEFAULTS = {
    "highway-v0": dict(simulation_frequency=15, policy_frequency=1, lanes_count=4, vehicles_count=50,
                       controlled_vehicles=1, initial_lane_id=None, duration=40, ego_spacing=2,
                       vehicles_density=1, collision_reward=-1, right_lane_reward=0.1, high_speed_reward=0.4,
                       lane_change_reward=0, reward_speed_range=[20, 30], normalize_reward=True,
                       offroad_terminal=False),
}
DEFAULTS["highway-fast-v0"] = dict(DEFAULTS["highway-v0"], simulation_frequency=5, lanes_count=3,
                                   vehicles_count=20, duration=30, ego_spacing=1.5)
STATIC_KEYS = ("simulation_frequency", "policy_frequency", "lanes_count", "vehicles_count", "controlled_vehicles")
OWN_KEYS = ("num_slots", "collision_cost", "idm", "on_road_reward", "batch_chunk")


def near_split(x: int, num_bins: int) -> list:
    """``utils.near_split(x, num_bins)``: the larger bins first."""
    quotient, remainder = divmod(x, num_bins)
    return [quotient + 1] * remainder + [quotient] * (num_bins - remainder)


def build_road(lanes_count: int):
    """``RoadNetwork.straight_road_network(lanes_count, speed_limit=30)``."""
    net = RoadNetwork()
    for lane in range(lanes_count):
        line_types = (C if lane == 0 else S, C if lane == lanes_count - 1 else N)
        net.add_lane("0", "1", L.straight([0.0, lane * L.DEFAULT_WIDTH], [LANE_LENGTH, lane * L.DEFAULT_WIDTH],
                                          line_types=line_types, speed_limit=SPEED_LIMIT))
    return net.freeze()


def default_batch_chunk(num_slots: int) -> int:
    """Environments a batched step runs at once on the CPU: the largest power of two with at most
    ``CHUNK_SLOTS`` vehicle slots (32 for ``highway-v0``), so that their neighbour search stays in the cache
    (docs/performance.md, "Large batches in chunks")."""
    return 1 << max(0, (CHUNK_SLOTS // num_slots).bit_length() - 1)


class Highway(Task):
    """The highway task for a given static layout."""

    route_length = 1

    def __init__(self, name: str, lanes_count: int, vehicles_count: int, controlled_vehicles: int,
                 num_slots: int, simulation_frequency: int, policy_frequency: int,
                 obs_config: kinematic_obs.KinematicsConfig, batch_chunk: int | None = None):
        self.name = name
        self.lanes_count = lanes_count
        self.road = build_road(lanes_count)
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.obs_config = obs_config
        others = near_split(vehicles_count, controlled_vehicles)
        controlled, slot = [], 0
        for n in others:
            controlled.append(slot)
            slot += 1 + n
        self.num_vehicles = slot
        self.num_slots = num_slots
        self.batch_chunk = batch_chunk
        self.controlled = tuple(controlled)
        is_controlled = np.zeros(num_slots, bool)
        is_controlled[controlled] = True
        self.is_controlled = is_controlled
        # highway-fast-v0: background vehicles do not check their own collisions
        self.check_collisions = is_controlled if name == "highway-fast-v0" else None
        self.spacing_factor = float(np.exp(-5 / 40 * lanes_count))

    def default_params(self) -> HighwayParams:
        raise NotImplementedError  # built by make_highway from the config

    def initial_vehicles(self, key, params: HighwayParams):
        """``_create_vehicles`` with the draws from ``key``."""
        return self.place(self.draws(key, params), params)

    def draws(self, key, params: HighwayParams) -> dict:
        """The random numbers of ``_create_vehicles`` per vehicle, list order: ``lane_id`` (controlled
        vehicles: ``initial_lane_id`` when set), ``speed`` (controlled: 25 m/s), ``factor`` (spacing
        draw) and ``delta`` (``randomize_behavior``; controlled: ``idm.delta``, unused)."""
        dtype = L.float_dtype()
        n = self.num_vehicles
        k_lane, k_speed, k_space, k_delta = jax.random.split(key, 4)
        ctrl = jnp.asarray(self.is_controlled[:n])
        lane_rand = jax.random.randint(k_lane, (n,), 0, self.lanes_count)
        lane_id = jnp.where(ctrl & (params.initial_lane_id >= 0), params.initial_lane_id, lane_rand)
        lo, hi = 0.7 * SPEED_LIMIT, 0.8 * SPEED_LIMIT
        speed = jnp.where(ctrl, EGO_SPEED, jax.random.uniform(k_speed, (n,), dtype, lo, hi))
        factor = jax.random.uniform(k_space, (n,), dtype, 0.9, 1.1)
        d_lo, d_hi = params.idm.delta_range
        delta = jnp.where(ctrl, params.idm.delta, jax.random.uniform(k_delta, (n,), dtype, d_lo, d_hi))
        return dict(lane_id=lane_id, speed=speed, factor=factor, delta=delta)

    def place(self, draws: dict, params: HighwayParams) -> dict:
        """Positions from the per-vehicle draws (``create_random``'s arithmetic, in list order).

        ``draws``: ``lane_id``, ``speed``, ``factor`` (the U(0.9, 1.1) spacing draw) and ``delta``
        for the first ``num_vehicles`` slots; the remaining slots are left empty.
        """
        dtype = L.float_dtype()
        n = self.num_vehicles
        ctrl = jnp.asarray(self.is_controlled[:n])
        speed = jnp.asarray(draws["speed"], dtype)
        spacing = jnp.where(ctrl, jnp.asarray(params.ego_spacing, dtype),
                            1 / jnp.asarray(params.vehicles_density, dtype))
        offset = spacing * (12 + 1.0 * speed) * self.spacing_factor

        def spawn(carry, inp):
            furthest, first = carry
            off, u = inp
            x0 = jnp.where(first, 3 * off, furthest)
            x0 = x0 + off * u
            return (jnp.where(first, x0, jnp.maximum(furthest, x0)), jnp.zeros((), bool)), x0

        init = (jnp.zeros((), dtype), jnp.ones((), bool))
        _, x = jax.lax.scan(spawn, init, (offset, jnp.asarray(draws["factor"], dtype)))
        pad = self.num_slots - n
        fill = lambda a, v: jnp.concatenate([a, jnp.full((pad,), v, a.dtype)])
        y = jnp.asarray(draws["lane_id"]).astype(dtype) * L.DEFAULT_WIDTH
        return dict(x=fill(x, 0.0), y=fill(y, 0.0), heading=jnp.zeros(self.num_slots, dtype),
                    speed=fill(speed, 0.0), alive=jnp.arange(self.num_slots) < n,
                    delta=fill(jnp.asarray(draws["delta"], dtype), params.idm.delta))

    def outcome(self, prev, state, action, params: HighwayParams):
        idx = np.asarray(self.controlled)
        crashed = state.crashed[idx]
        on_road = state.on_road[idx]
        dtype = state.x.dtype
        lane_id = jnp.asarray(self.road.lane_id)[state.target_lane[idx]].astype(dtype)
        right_lane = lane_id / max(self.lanes_count - 1, 1)
        forward = state.speed[idx] * trig.cos(state.heading[idx])
        lo, hi = params.reward_speed_range
        high_speed = jnp.clip(0 + (forward - lo) * (1 - 0) / (hi - lo), 0, 1)
        col = crashed.astype(dtype)
        onr = on_road.astype(dtype)
        reward = (params.collision_reward * col + params.right_lane_reward * right_lane
                  + params.high_speed_reward * high_speed + params.on_road_reward * onr)
        best = params.high_speed_reward + params.right_lane_reward
        normalised = 0 + (reward - params.collision_reward) * (1 - 0) / (best - params.collision_reward)
        reward = jnp.where(params.normalize_reward, normalised, reward) * onr
        cost = (params.collision_cost * crashed).astype(dtype)
        terminated = crashed | (params.offroad_terminal & ~on_road)
        info = {"rewards": {"collision_reward": col, "right_lane_reward": right_lane,
                            "high_speed_reward": high_speed, "on_road_reward": onr}}
        return reward.astype(dtype), cost, terminated, info


# ----------------------------------------------------------------------------------------------
# Configuration: highway-env's config dict and keyword overrides -> a TrafficEnv

def make_highway(name: str, env_config: dict | None = None, **overrides) -> TrafficEnv:
    """``highway-v0`` / ``highway-fast-v0`` from highway-env's config keys (``env_config`` and/or keywords).

    Keywords are highway-env config keys (``controlled_vehicles=3``, ``vehicles_count``, ``lanes_count``,
    ``duration``, ``observation``, ``action``, the reward keys, ...) plus ``num_slots`` (vehicle slots,
    >= controlled_vehicles + vehicles_count; the extra ones stay empty), ``collision_cost``, ``idm``
    (an :class:`~envs_jax.idm.IDMParams` or a dict of its fields) and ``batch_chunk`` (environments a batched
    step runs at once on the CPU, None: the whole batch; default :func:`default_batch_chunk`; results are the whole
    batch's up to last-bit rounding). Unknown keys or bad values raise
    ``ValueError`` naming them and what is allowed.
    """
    cfg = dict(DEFAULTS[name])
    cfg["observation"] = {"type": "Kinematics"}
    cfg["action"] = {"type": "DiscreteMetaAction"}
    cfg.update(config_given(name, cfg, OWN_KEYS, env_config, overrides))  # one road: no connected lanes

    sim = int_value(name, "simulation_frequency", cfg["simulation_frequency"], 1)
    pol = int_value(name, "policy_frequency", cfg["policy_frequency"], 1, sim)
    lanes_count = int_value(name, "lanes_count", cfg["lanes_count"], 1)
    vehicles_count = int_value(name, "vehicles_count", cfg["vehicles_count"], 0)
    k = int_value(name, "controlled_vehicles", cfg["controlled_vehicles"], 1)
    total = k + vehicles_count
    num_slots = cfg.get("num_slots", total)
    num_slots = int_value(name, "num_slots", num_slots, total)
    lane0 = cfg["initial_lane_id"]
    if lane0 is not None:
        lane0 = int_value(name, "initial_lane_id", lane0, 0, lanes_count - 1)
    obs_cfg = observation_config(name, cfg["observation"])
    action = meta_action_config(name, cfg["action"])
    rsr = speed_range(name, cfg["reward_speed_range"])
    for key in ("normalize_reward", "offroad_terminal"):
        flag_value(name, key, cfg[key])
    idm = idm_params(name, cfg.get("idm"))
    chunk = cfg.get("batch_chunk", default_batch_chunk(num_slots))
    if chunk is not None and (isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1):
        raise ValueError(f"{name}: batch_chunk must be None (the whole batch at once) or an integer >= 1, "
                         f"got {chunk!r}")
    chunk = None if chunk is None else int(chunk)
    task = Highway(name, lanes_count, vehicles_count, k, num_slots, sim, pol, obs_cfg, chunk)
    params = HighwayParams(
        duration=number_value(name, "duration", cfg["duration"], positive=True),
        collision_cost=cost_value(name, "collision_cost", cfg.get("collision_cost", 5.0)),
        target_speeds=action.get("target_speeds", np.linspace(20, 30, 3)),
        idm=idm, obstacles=None,
        ego_spacing=number_value(name, "ego_spacing", cfg["ego_spacing"], positive=True),
        vehicles_density=number_value(name, "vehicles_density", cfg["vehicles_density"], positive=True),
        initial_lane_id=-1 if lane0 is None else lane0,
        collision_reward=number_value(name, "collision_reward", cfg["collision_reward"]),
        right_lane_reward=number_value(name, "right_lane_reward", cfg["right_lane_reward"]),
        high_speed_reward=number_value(name, "high_speed_reward", cfg["high_speed_reward"]),
        lane_change_reward=number_value(name, "lane_change_reward", cfg["lane_change_reward"]),
        on_road_reward=number_value(name, "on_road_reward", cfg.get("on_road_reward", 0.0)),
        reward_speed_range=(float(rsr[0]), float(rsr[1])),
        normalize_reward=bool(cfg["normalize_reward"]), offroad_terminal=bool(cfg["offroad_terminal"]),
    )
    if params.normalize_reward and params.high_speed_reward + params.right_lane_reward == params.collision_reward:
        raise ValueError(f"{name}: normalize_reward needs high_speed_reward + right_lane_reward != collision_reward")
    return TrafficEnv(task, params)
