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

__all__ = ["IDM_CLASS", "RENDER_KEYS", "config_given", "flag_value", "idm_params", "int_value", "meta_action_config",
           "number_value", "observation_config", "speed_range", "unwrap_section"]

# highway-env's IDM drivers, the only other_vehicles_type the tasks simulate
IDM_CLASS = "highway_env.vehicle.behavior.IDMVehicle"
# highway-env config keys that only affect rendering (accepted and ignored)
RENDER_KEYS = frozenset({"screen_width", "screen_height", "centering_position", "scaling", "show_trajectories",
                         "render_agent", "offscreen_rendering", "real_time_rendering", "render_mode"})


def int_value(name, key, value, lo, hi=None):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo or (hi is not None and value > hi):
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


def speed_range(name, value):
    """``reward_speed_range``: ``[low, high]`` with ``low != high``."""
    if np.shape(value) != (2,) or not float(value[1]) != float(value[0]):
        raise ValueError(f"{name}: reward_speed_range must be [low, high] with low != high, got {value!r}")
    return value


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


def observation_config(name, value):
    obs = unwrap_section(name, "observation", value, "MultiAgentObservation", "observation_config")
    return kinematic_obs.KinematicsConfig.from_config(obs, where=f"{name}: observation")


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
    return idm


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
