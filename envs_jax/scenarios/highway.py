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

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import kinematic_obs
from envs_jax import lanes as L
from envs_jax.idm import IDMParams
from envs_jax.road import RoadNetwork
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams

C, S, N = L.LINE_CONTINUOUS_LINE, L.LINE_STRIPED, L.LINE_NONE
LANE_LENGTH = 10000.0
SPEED_LIMIT = 30.0
EGO_SPEED = 25.0
IDM_CLASS = "highway_env.vehicle.behavior.IDMVehicle"


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
# highway-env config keys that only affect rendering (accepted and ignored)
RENDER_KEYS = frozenset({"screen_width", "screen_height", "centering_position", "scaling", "show_trajectories",
                         "render_agent", "offscreen_rendering", "real_time_rendering", "render_mode"})
OWN_KEYS = ("num_slots", "collision_cost", "idm", "on_road_reward")


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


class Highway(Task):
    """The highway task for a given static layout."""

    route_length = 1

    def __init__(self, name: str, lanes_count: int, vehicles_count: int, controlled_vehicles: int,
                 num_slots: int, simulation_frequency: int, policy_frequency: int,
                 obs_config: kinematic_obs.KinematicsConfig):
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
        spacing = jnp.where(ctrl, jnp.asarray(params.ego_spacing, dtype), 1 / jnp.asarray(params.vehicles_density, dtype))
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
        forward = state.speed[idx] * jnp.cos(state.heading[idx])
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

def _int(name, key, value, lo, hi=None):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo or (hi is not None and value > hi):
        rng = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise ValueError(f"{name}: {key} must be an integer {rng}, got {value!r}")
    return int(value)


def _number(name, key, value, positive=False):
    if (isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating))
            or not np.isfinite(float(value))):
        raise ValueError(f"{name}: {key} must be a finite number, got {value!r}")
    if positive and not float(value) > 0:
        raise ValueError(f"{name}: {key} must be > 0, got {value!r}")
    return float(value)


def _unwrap(name, section, value, multi, inner):
    if not isinstance(value, dict):
        raise ValueError(f"{name}: {section} must be a dict, got {value!r}")
    if value.get("type") == multi:
        extra = sorted(k for k in value if k not in ("type", inner))
        if extra:
            raise ValueError(f"{name}: {section} keys {extra} are not understood; allowed: ['type', '{inner}']")
        value = value.get(inner, {})
        if not isinstance(value, dict):
            raise ValueError(f"{name}: {section}.{inner} must be a dict, got {value!r}")
    return dict(value)


def _action(name, value):
    action = _unwrap(name, "action", value, "MultiAgentAction", "action_config")
    kind = action.pop("type", None)
    if kind != "DiscreteMetaAction":
        raise ValueError(f"{name}: action type must be 'DiscreteMetaAction' (or MultiAgentAction of it), got {kind!r}")
    out = {}
    for key in ("longitudinal", "lateral"):
        if action.pop(key, True) is not True:
            raise ValueError(f"{name}: DiscreteMetaAction({key}=False) is not supported; the five meta-actions "
                             f"{('LANE_LEFT', 'IDLE', 'LANE_RIGHT', 'FASTER', 'SLOWER')} are")
    if "target_speeds" in action:
        ts = np.asarray(action.pop("target_speeds"), dtype=np.float64)
        if ts.ndim != 1 or ts.size < 2 or not np.all(np.diff(ts) > 0) or not np.all(np.isfinite(ts)):
            raise ValueError(f"{name}: target_speeds must be an increasing list of at least 2 finite speeds, "
                             f"got {ts.tolist()}")
        out["target_speeds"] = ts
    if action:
        raise ValueError(f"{name}: DiscreteMetaAction keys {sorted(action)} are not understood; allowed: "
                         f"['type', 'longitudinal', 'lateral', 'target_speeds']")
    return out


def _observation(name, value):
    obs = _unwrap(name, "observation", value, "MultiAgentObservation", "observation_config")
    return kinematic_obs.KinematicsConfig.from_config(obs, where=f"{name}: observation")


def _cost(name, key, value):
    """A cost (or cost weight): a finite number >= 0."""
    value = _number(name, key, value)
    if value < 0:
        raise ValueError(f"{name}: {key} is a cost and must be >= 0, got {value!r}")
    return value


def _speed_range(name, rsr):
    """``reward_speed_range``: ``[low, high]`` of finite speeds with ``low != high`` (the reward divides by
    ``high - low``)."""
    try:
        arr = np.asarray(rsr, np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (2,) or not np.all(np.isfinite(arr)) or arr[0] == arr[1]:
        raise ValueError(f"{name}: reward_speed_range must be [low, high] of finite speeds with low != high, "
                         f"got {rsr!r}")
    return float(arr[0]), float(arr[1])


# Physical ranges of IDMParams fields: (low, high, low allowed, what); every field must also be finite
_IDM_RANGES = {
    "acc_max": (0.0, None, False, "an acceleration in m/s^2"),
    "comfort_acc_max": (0.0, None, False, "an acceleration in m/s^2"),
    "comfort_acc_min": (None, 0.0, False, "a deceleration in m/s^2 (negative)"),
    "distance_wanted": (0.0, None, True, "a jam distance in metres"),
    "time_wanted": (0.0, None, True, "a time gap in seconds"),
    "delta": (0.0, None, False, "an exponent"),
    "politeness": (0.0, 1.0, True, "a weight in [0, 1]"),
    "lane_change_min_acc_gain": (0.0, None, True, "an acceleration in m/s^2"),
    "lane_change_max_braking_imposed": (0.0, None, True, "an acceleration in m/s^2"),
    "lane_change_delay": (0.0, None, True, "a time in seconds"),
}


def check_idm(name, idm: IDMParams) -> IDMParams:
    """``idm`` if each field is in its physical range (``_IDM_RANGES``; ``delta_range`` is (low, high) with
    0 < low <= high), else ``ValueError`` naming the field and the allowed range."""
    for key, (low, high, low_ok, what) in _IDM_RANGES.items():
        value = getattr(idm, key)
        try:
            value = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{name}: idm {key} must be a number, got {value!r}") from None
        ok = np.isfinite(value) and (low is None or (value >= low if low_ok else value > low)) \
            and (high is None or (value <= high if low_ok else value < high))
        if not ok:
            bound = " and ".join(b for b in (None if low is None else f"{'>=' if low_ok else '>'} {low:g}",
                                             None if high is None else f"{'<=' if low_ok else '<'} {high:g}") if b)
            raise ValueError(f"{name}: idm {key} is {what} and must be {bound}, got {value!r}")
    dr = np.asarray(idm.delta_range, np.float64) if np.ndim(idm.delta_range) == 1 else None
    if dr is None or dr.shape != (2,) or not np.all(np.isfinite(dr)) or not 0 < dr[0] <= dr[1]:
        raise ValueError(f"{name}: idm delta_range must be (low, high) of exponents with 0 < low <= high, "
                         f"got {idm.delta_range!r}")
    return idm


def _idm(name, idm):
    """The ``idm`` key: None (highway-env's constants), an IDMParams or a dict of its fields."""
    if idm is None:
        return IDMParams()
    if isinstance(idm, dict):
        fields = {f.name for f in dataclasses.fields(IDMParams)}
        bad = sorted(set(idm) - fields)
        if bad:
            raise ValueError(f"{name}: unknown idm field(s) {bad}; allowed: {sorted(fields)}")
        idm = IDMParams(**idm)
    if not isinstance(idm, IDMParams):
        raise ValueError(f"{name}: idm must be an IDMParams or a dict of its fields, got {type(idm).__name__}")
    return check_idm(name, idm)


def config_given(name: str, cfg: dict, own_keys, env_config, overrides, connected_lanes: str | None = None) -> dict:
    """The keys a traffic task's caller set (``env_config``, then keywords), after the checks every task shares.

    Unknown keys, another ``other_vehicles_type`` than highway-env's IDM drivers and ``manual_control=True`` raise
    ``ValueError``; rendering keys are dropped. ``neighbour_vehicles_connected_lanes=True`` is refused with
    ``connected_lanes`` as the reason, or ignored where that is None (roads without connected lanes).
    """
    given = dict(env_config or {})
    given.update(overrides)
    allowed = sorted(set(cfg) | set(own_keys) | RENDER_KEYS
                     | {"other_vehicles_type", "manual_control", "neighbour_vehicles_connected_lanes"})
    unknown = sorted(k for k in given if k not in allowed)
    if unknown:
        raise ValueError(f"{name}: unknown config key(s) {unknown}; allowed: {allowed}")
    for key in RENDER_KEYS:
        given.pop(key, None)
    if given.pop("other_vehicles_type", IDM_CLASS) != IDM_CLASS:
        raise ValueError(f"{name}: other_vehicles_type must be {IDM_CLASS!r} (the IDM/MOBIL drivers)")
    if given.pop("manual_control", False):
        raise ValueError(f"{name}: manual_control=True is not supported (there is no keyboard in JAX)")
    if given.pop("neighbour_vehicles_connected_lanes", False) and connected_lanes is not None:
        raise ValueError(f"{name}: neighbour_vehicles_connected_lanes=True is not supported: {connected_lanes}")
    return given


def make_highway(name: str, env_config: dict | None = None, **overrides) -> TrafficEnv:
    """``highway-v0`` / ``highway-fast-v0`` from highway-env's config keys (``env_config`` and/or keywords).

    Keywords are highway-env config keys (``controlled_vehicles=3``, ``vehicles_count``, ``lanes_count``,
    ``duration``, ``observation``, ``action``, the reward keys, ...) plus ``num_slots`` (vehicle slots,
    >= controlled_vehicles + vehicles_count; the extra ones stay empty), ``collision_cost`` and ``idm``
    (an :class:`~envs_jax.idm.IDMParams` or a dict of its fields). Unknown keys or bad values raise
    ``ValueError`` naming them and what is allowed.
    """
    cfg = dict(DEFAULTS[name])
    cfg["observation"] = {"type": "Kinematics"}
    cfg["action"] = {"type": "DiscreteMetaAction"}
    cfg.update(config_given(name, cfg, OWN_KEYS, env_config, overrides))  # one road: no connected lanes

    sim = _int(name, "simulation_frequency", cfg["simulation_frequency"], 1)
    pol = _int(name, "policy_frequency", cfg["policy_frequency"], 1, sim)
    lanes_count = _int(name, "lanes_count", cfg["lanes_count"], 1)
    vehicles_count = _int(name, "vehicles_count", cfg["vehicles_count"], 0)
    k = _int(name, "controlled_vehicles", cfg["controlled_vehicles"], 1)
    total = k + vehicles_count
    num_slots = cfg.get("num_slots", total)
    num_slots = _int(name, "num_slots", num_slots, total)
    lane0 = cfg["initial_lane_id"]
    if lane0 is not None:
        lane0 = _int(name, "initial_lane_id", lane0, 0, lanes_count - 1)
    obs_cfg = _observation(name, cfg["observation"])
    action = _action(name, cfg["action"])
    rsr = _speed_range(name, cfg["reward_speed_range"])
    for key in ("normalize_reward", "offroad_terminal"):
        if not isinstance(cfg[key], (bool, np.bool_)):
            raise ValueError(f"{name}: {key} must be True or False, got {cfg[key]!r}")
    idm = _idm(name, cfg.get("idm"))
    task = Highway(name, lanes_count, vehicles_count, k, num_slots, sim, pol, obs_cfg)
    params = HighwayParams(
        duration=_number(name, "duration", cfg["duration"], positive=True),
        collision_cost=_cost(name, "collision_cost", cfg.get("collision_cost", 5.0)),
        target_speeds=action.get("target_speeds", np.linspace(20, 30, 3)),
        idm=idm, obstacles=None,
        ego_spacing=_number(name, "ego_spacing", cfg["ego_spacing"], positive=True),
        vehicles_density=_number(name, "vehicles_density", cfg["vehicles_density"], positive=True),
        initial_lane_id=-1 if lane0 is None else lane0,
        collision_reward=_number(name, "collision_reward", cfg["collision_reward"]),
        right_lane_reward=_number(name, "right_lane_reward", cfg["right_lane_reward"]),
        high_speed_reward=_number(name, "high_speed_reward", cfg["high_speed_reward"]),
        lane_change_reward=_number(name, "lane_change_reward", cfg["lane_change_reward"]),
        on_road_reward=_number(name, "on_road_reward", cfg.get("on_road_reward", 0.0)),
        reward_speed_range=rsr,
        normalize_reward=bool(cfg["normalize_reward"]), offroad_terminal=bool(cfg["offroad_terminal"]),
    )
    if params.normalize_reward and params.high_speed_reward + params.right_lane_reward == params.collision_reward:
        raise ValueError(f"{name}: normalize_reward needs high_speed_reward + right_lane_reward != collision_reward")
    return TrafficEnv(task, params)
