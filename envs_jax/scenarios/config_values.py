"""Checks of highway-env configuration values that every traffic task shares.

A task's factory (``make_highway``, ``make_merge``, ...) reads highway-env's config dict with these: integers and
numbers in range, the ``MultiAgent*`` wrappers of the action and observation sections, the meta-action and
kinematics-observation sections, the drivers' IDM constants, and the keys a caller may set at all
(:func:`config_given`). Every problem raises ``ValueError`` naming the task, the key and what is allowed.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from envs_jax import kinematic_obs
from envs_jax.idm import IDMParams

__all__ = ["IDM_CLASS", "IDM_RANGES", "RENDER_KEYS", "check_idm", "config_given", "continuous_action_config",
           "cost_value", "flag_value", "idm_params", "int_value", "meta_action_config", "number_value",
           "observation_config", "speed_range", "unwrap_section"]

# highway-env's IDM drivers, the only other_vehicles_type the tasks simulate
IDM_CLASS = "highway_env.vehicle.behavior.IDMVehicle"
# highway-env config keys that only affect rendering (accepted and ignored)
RENDER_KEYS = frozenset({"screen_width", "screen_height", "centering_position", "scaling", "show_trajectories",
                         "render_agent", "offscreen_rendering", "real_time_rendering", "render_mode"})


def int_value(name, key, value, lo, hi=None):
    if (isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo
            or (hi is not None and value > hi)):
        rng = f">= {lo}" if hi is None else f"in {lo}..{hi}"
        raise ValueError(f"{name}: {key} must be an integer {rng}, got {value!r}")
    return int(value)


def number_value(name, key, value, positive=False):
    if (isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating))
            or not np.isfinite(float(value))):
        raise ValueError(f"{name}: {key} must be a finite number, got {value!r}")
    if positive and not float(value) > 0:
        raise ValueError(f"{name}: {key} must be > 0, got {value!r}")
    return float(value)


def flag_value(name, key, value) -> bool:
    """A config key that must be True or False."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: {key} must be True or False, got {value!r}")
    return bool(value)


def cost_value(name, key, value):
    """A cost (or cost weight): a finite number >= 0."""
    value = number_value(name, key, value)
    if value < 0:
        raise ValueError(f"{name}: {key} is a cost and must be >= 0, got {value!r}")
    return value


def speed_range(name, value):
    """``reward_speed_range``: ``(low, high)`` of finite speeds with ``low != high`` (the reward divides by
    ``high - low``)."""
    try:
        arr = np.asarray(value, np.float64)
    except (TypeError, ValueError):
        arr = None
    if arr is None or arr.shape != (2,) or not np.all(np.isfinite(arr)) or arr[0] == arr[1]:
        raise ValueError(f"{name}: reward_speed_range must be [low, high] of finite speeds with low != high, "
                         f"got {value!r}")
    return float(arr[0]), float(arr[1])


def unwrap_section(name, section, value, multi, inner):
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


def meta_action_config(name, value):
    action = unwrap_section(name, "action", value, "MultiAgentAction", "action_config")
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


def continuous_action_config(name, value, dynamical: bool, default_target_speeds) -> tuple:
    """A ``ContinuousAction`` section (or ``MultiAgentAction`` of it): ``(longitudinal, lateral, values)`` with
    ``values`` the ``acceleration_range``, ``steering_range`` (highway-env's defaults +-5 m/s^2, +-pi/4 when
    absent) and ``target_speeds`` (read but unused by ``ContinuousAction``). ``dynamical`` is the one vehicle
    model the task simulates (True: ``BicycleVehicle``, False: the kinematic ``Vehicle``)."""
    action = unwrap_section(name, "action", value, "MultiAgentAction", "action_config")
    kind = action.pop("type", None)
    if kind != "ContinuousAction":
        raise ValueError(f"{name}: action type must be 'ContinuousAction' (or MultiAgentAction of it), got {kind!r}")
    lon, lat = action.pop("longitudinal", True), action.pop("lateral", True)
    if not isinstance(lon, (bool, np.bool_)) or not isinstance(lat, (bool, np.bool_)) or not (lon or lat):
        raise ValueError(f"{name}: ContinuousAction needs longitudinal and/or lateral True, got "
                         f"longitudinal={lon!r}, lateral={lat!r}")
    out = {}
    for key, default in (("acceleration_range", (-5.0, 5.0)), ("steering_range", (-np.pi / 4, np.pi / 4))):
        rng = action.pop(key, None)
        rng = default if rng is None else rng
        if (np.shape(rng) != (2,) or not np.all(np.isfinite(np.asarray(rng, float)))
                or not float(rng[0]) < float(rng[1])):
            raise ValueError(f"{name}: {key} must be [low, high] with finite low < high, got {rng!r}")
        out[key] = (float(rng[0]), float(rng[1]))
    target_speeds = np.asarray(action.pop("target_speeds", default_target_speeds), np.float64)
    if target_speeds.ndim != 1 or target_speeds.size < 2 or not np.all(np.diff(target_speeds) > 0):
        raise ValueError(f"{name}: target_speeds must be an increasing list of at least 2 speeds, "
                         f"got {target_speeds.tolist()}")
    out["target_speeds"] = target_speeds
    given = action.pop("dynamical", False)
    if not isinstance(given, (bool, np.bool_)) or bool(given) != dynamical:
        model = "the BicycleVehicle (dynamical=True)" if dynamical else "the kinematic Vehicle (dynamical=False)"
        raise ValueError(f"{name}: ContinuousAction(dynamical={given!r}) is not supported; {model} is")
    if action.pop("clip", True) is not True:
        raise ValueError(f"{name}: ContinuousAction(clip=False) is not supported; actions are clipped to [-1, 1]")
    if action.pop("speed_range", None) is not None:
        raise ValueError(f"{name}: ContinuousAction speed_range is not supported; speeds stay in [-40, 40] m/s")
    if action:
        raise ValueError(f"{name}: ContinuousAction keys {sorted(action)} are not understood; allowed: "
                         f"['type', 'longitudinal', 'lateral', 'acceleration_range', 'steering_range', "
                         f"'target_speeds', 'dynamical', 'clip', 'speed_range']")
    return bool(lon), bool(lat), out


def observation_config(name, value):
    obs = unwrap_section(name, "observation", value, "MultiAgentObservation", "observation_config")
    return kinematic_obs.KinematicsConfig.from_config(obs, where=f"{name}: observation")


# Physical ranges of IDMParams fields: (low, high, bounds allowed, what); every field must also be finite
IDM_RANGES = {
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
    """``idm`` if each field is in its physical range (``IDM_RANGES``; ``delta_range`` is (low, high) with
    0 < low <= high), else ``ValueError`` naming the field and the allowed range."""
    for key, (low, high, low_ok, what) in IDM_RANGES.items():
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


def idm_params(name, idm, default: IDMParams | None = None) -> IDMParams:
    """The ``idm`` key: None (``default``, highway-env's constants when None), an IDMParams, or a dict of its fields
    replacing those of ``default``."""
    default = IDMParams() if default is None else default
    if idm is None:
        return default
    if isinstance(idm, dict):
        fields = {f.name for f in dataclasses.fields(IDMParams)}
        bad = sorted(set(idm) - fields)
        if bad:
            raise ValueError(f"{name}: unknown idm field(s) {bad}; allowed: {sorted(fields)}")
        idm = dataclasses.replace(default, **idm)
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


def keywords_only(name, env_config, values: dict, param_keys, other_keys) -> None:
    """The authors' K-agent tasks take keywords only: refuse an ``env_config`` dict and any keyword outside
    ``param_keys`` (the params' numbers) and ``other_keys`` (the factory's own), naming what is allowed."""
    allowed = ", ".join(list(other_keys) + list(param_keys))
    if env_config is not None:
        raise ValueError(f"{name}: env_config is not read; give the values as keywords ({allowed})")
    unknown = sorted(set(values) - set(param_keys))
    if unknown:
        raise ValueError(f"{name}: unknown parameter(s) {unknown}; allowed: {allowed}")


def agents_layout(name, controlled_vehicles, other_vehicles, vehicles_count, simulation_frequency, policy_frequency,
                  min_agents: int, max_agents: int, max_traffic: int) -> tuple[int, int, int, int, int]:
    """``(K, N, vehicles_count, simulation_frequency, policy_frequency)`` of an authors' K-agent task, each checked:
    K agents in ``min_agents..max_agents``, N traffic vehicles in ``0..max_traffic``, 2..K + N observation rows
    (default K), ``0 < policy_frequency <= simulation_frequency``."""
    k = int_value(name, "controlled_vehicles", controlled_vehicles, min_agents, max_agents)
    n = int_value(name, "other_vehicles", other_vehicles, 0, max_traffic)
    count = int_value(name, "vehicles_count", k if vehicles_count is None else vehicles_count, 2, k + n)
    sim = int_value(name, "simulation_frequency", simulation_frequency, 1)
    pol = int_value(name, "policy_frequency", policy_frequency, 1, sim)
    return k, n, count, sim, pol
