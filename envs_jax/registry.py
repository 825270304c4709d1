"""``envs_jax.make``: scenario lookup, parameter overrides and the authors' ``env_config.json``."""

from __future__ import annotations

import dataclasses
from typing import Any, Callable

import numpy as np

from envs_jax.env import DrivingEnv, Scenario

_SCENARIOS: dict[str, Callable[[], Scenario]] = {}
# traffic tasks (V vehicle slots, K controlled): name -> factory(name, env_config, **overrides) -> TrafficEnv
_TASKS: dict[str, Callable[..., Any]] = {}
_TASKS_WITH_ACTION_MODE: set[str] = set()  # tasks whose factory takes ``action_mode`` (the authors' continuous ones)
_CACHE: dict[str, Scenario] = {}

STATIC_KEYS = ("simulation_frequency", "policy_frequency")

# env_config.json keys that only affect rendering or bookkeeping of the original code.
_RENDER_KEYS = frozenset({"screen_width", "screen_height", "scaling", "centering_position", "show_trajectories",
                          "render_agent", "offscreen_rendering", "manual_control", "real_time_rendering",
                          "render_mode", "other_vehicles_type", "controlled_vehicles", "normalize_reward",
                          "offroad_terminal", "neighbour_vehicles_connected_lanes"})

_EXPECTED_OBS = {"type": "Kinematics", "features": ["x", "y", "vx", "vy"], "vehicles_count": 2,
                 "absolute": True, "normalize": False}


def register(name: str, factory: Callable[[], Scenario]) -> None:
    _SCENARIOS[name] = factory


def register_task(name: str, factory: Callable[..., Any], takes_action_mode: bool = False) -> None:
    """Register a traffic task: ``factory(name, env_config, **overrides)`` returns its environment
    (``takes_action_mode``: ``make``'s ``action_mode`` is passed on as a keyword)."""
    _TASKS[name] = factory
    if takes_action_mode:
        _TASKS_WITH_ACTION_MODE.add(name)


def available_scenarios() -> list[str]:
    """Names of the two-agent scenarios accepted by :func:`make`."""
    return sorted(_SCENARIOS)


def available_tasks() -> list[str]:
    """Names of the traffic tasks accepted by :func:`make` (V vehicle slots, K controlled)."""
    return sorted(_TASKS)


def _scenario(name: str, action_mode: str | None = None) -> Scenario:
    if name not in _SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; "
                         f"available: {', '.join(available_scenarios() + available_tasks())}")
    key = (name, action_mode)
    if key not in _CACHE:
        if action_mode is None:
            _CACHE[key] = _SCENARIOS[name]()
        else:
            probe = _scenario(name)
            if probe.discrete:
                raise ValueError(f"{name}: action_mode only applies to the continuous scenarios "
                                 f"(intersection, racetrack); {name} uses discrete meta-actions")
            _CACHE[key] = _SCENARIOS[name](action_mode=action_mode)
    return _CACHE[key]


def make(name: str, env_config: dict | None = None, action_mode: str | None = None, **overrides: Any) -> DrivingEnv:
    """Create a scenario's environment.

    ``overrides`` are fields of the scenario's params (see ``env.default_params``)
    or the static ``simulation_frequency`` / ``policy_frequency``. ``action_mode``
    ("longitudinal", "lateral" or "both") selects the continuous action model of
    intersection / racetrack (defaults: longitudinal, lateral).
    ``env_config`` is the original repository's ``env_config.json`` dict; the
    keys that apply are translated, rendering keys are ignored, and anything
    else raises ``ValueError``.
    """
    if name in _TASKS:
        if action_mode is not None and name in _TASKS_WITH_ACTION_MODE:
            overrides["action_mode"] = action_mode
        elif action_mode is not None:
            raise ValueError(f"{name}: action_mode does not apply (discrete meta-actions); set 'action' instead")
        return _TASKS[name](name, env_config, **overrides)
    if env_config is not None and action_mode is None:
        action_mode = _action_mode_from_config(_scenario(name), env_config)
    scenario = _scenario(name, action_mode)
    params = scenario.default_params()
    static = {"simulation_frequency": scenario.simulation_frequency,
              "policy_frequency": scenario.policy_frequency}
    values: dict[str, Any] = {}
    if env_config is not None:
        values.update(_translate_env_config(scenario, params, env_config))
    values.update(overrides)
    fields = {f.name for f in dataclasses.fields(params)}
    unknown = sorted(k for k in values if k not in fields and k not in STATIC_KEYS)
    if unknown:
        raise ValueError(f"{name}: unknown parameter(s) {unknown}; allowed: {sorted(fields) + list(STATIC_KEYS)}")
    for key in STATIC_KEYS:
        if key in values:
            static[key] = values.pop(key)
    sim, pol = static["simulation_frequency"], static["policy_frequency"]
    if not (isinstance(sim, (int, np.integer)) and isinstance(pol, (int, np.integer)) and 0 < pol <= sim):
        raise ValueError(f"{name}: simulation_frequency and policy_frequency must be integers with "
                         f"0 < policy_frequency <= simulation_frequency, got {sim} and {pol}")
    values = {k: _check_value(name, params, k, v) for k, v in values.items()}
    check_ranges(name, params, values)
    params = params.replace(**values)
    return DrivingEnv(scenario, sim, pol, params)


def _check_value(name, params, key, value):
    default = getattr(params, key)
    if default is None or value is None:
        return value
    if np.ndim(default) == 0:
        if not np.isscalar(value) and np.ndim(value) != 0:
            raise ValueError(f"{name}: parameter {key!r} must be a number, got {value!r}")
        if not np.isfinite(float(value)):
            raise ValueError(f"{name}: parameter {key!r} must be finite, got {value!r}")
        return float(value)
    arr = np.asarray(value, dtype=np.float64)
    if key == "target_speeds":
        if arr.ndim != 1 or arr.size < 2 or not np.all(np.diff(arr) > 0):
            raise ValueError(f"{name}: target_speeds must be an increasing list of at least 2 speeds, got {value!r}")
        return arr
    if arr.shape[1:] != np.shape(default)[1:] or (key != "obstacles" and arr.shape != np.shape(default)):
        raise ValueError(f"{name}: parameter {key!r} must have shape {np.shape(default)}, got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name}: parameter {key!r} must be finite, got {value!r}")
    return arr


# Physical ranges of params fields, wherever a scenario has them: (lower bound, whether the bound itself is
# allowed, what the number is). Rewards may take either sign; positions and headings only need to be finite.
_RANGES = {
    "duration": (0.0, False, "an episode length in seconds"),
    "collision_cost": (0.0, True, "a cost"),
    "lane_centering_cost": (0.0, True, "a cost weight (1 / (1 + w * lateral^2))"),
    "offroad_cost": (0.0, True, "a cost"),
    "start_noise": (0.0, True, "a standard deviation in metres"),
    "start_s": (0.0, True, "a distance along the start lane in metres"),
    "arrival_s": (0.0, True, "a distance along the exit lane in metres"),
    "speed_band_low": (0.0, True, "a speed in m/s"),
    "speed_band_high": (0.0, True, "a speed in m/s"),
    "target_speeds": (0.0, True, "speeds in m/s"),
}


def check_ranges(name: str, params, values: dict) -> None:
    """Reject overrides outside their physical range (``ValueError`` naming the key and the allowed range)."""
    for key, value in values.items():
        if key not in _RANGES or value is None:
            continue
        low, inclusive, what = _RANGES[key]
        arr = np.asarray(value, dtype=np.float64)
        if not np.all(arr >= low if inclusive else arr > low):
            raise ValueError(f"{name}: parameter {key!r} is {what} and must be {'>=' if inclusive else '>'} {low:g}, "
                             f"got {np.asarray(value).tolist()!r}")
    merged = lambda key: values[key] if key in values else getattr(params, key, None)
    if ("speed_band_low" in values or "speed_band_high" in values) and merged("speed_band_low") is not None:
        lo, hi = float(merged("speed_band_low")), float(merged("speed_band_high"))
        if lo > hi:
            raise ValueError(f"{name}: speed_band_low ({lo:g}) must not exceed speed_band_high ({hi:g})")
    for key in ("acceleration_range", "steering_range"):
        if key in values and values[key] is not None:
            lo, hi = np.asarray(values[key], dtype=np.float64).tolist()
            if not lo < hi:
                raise ValueError(f"{name}: parameter {key!r} must be (low, high) with low < high, got {[lo, hi]}")
    if "obstacles" in values and values["obstacles"] is not None:
        sizes = np.asarray(values["obstacles"], dtype=np.float64)[:, 3:5]
        if not np.all(sizes > 0):
            raise ValueError(f"{name}: obstacles rows are [x, y, heading, length, width] with length and width "
                             f"> 0 metres, got lengths/widths {sizes.tolist()}")


def _translate_env_config(scenario: Scenario, params, config: dict) -> dict:
    name = scenario.name
    out: dict[str, Any] = {}
    for key, value in config.items():
        if key in ("duration", "simulation_frequency", "policy_frequency"):
            out[key] = value
        elif key == "action":
            out.update(_translate_action(scenario, value))
        elif key == "observation":
            _check_observation(name, value)
        elif key in _RENDER_KEYS or key in scenario.inert_config_keys:
            continue
        elif key in {f.name for f in dataclasses.fields(params)}:
            out[key] = value
        else:
            raise ValueError(f"{name}: env_config key {key!r} is not understood; understood keys: duration, "
                             f"simulation_frequency, policy_frequency, action, observation, the params fields, "
                             f"and (ignored) {sorted(_RENDER_KEYS | scenario.inert_config_keys)}")
    return out


def _translate_action(scenario: Scenario, action: dict) -> dict:
    name = scenario.name
    if action.get("type") == "MultiAgentAction":
        action = action.get("action_config", {})
    kind = action.get("type")
    if scenario.discrete:
        if kind != "DiscreteMetaAction":
            raise ValueError(f"{name}: action type must be DiscreteMetaAction, got {kind!r}")
        out = {}
        if "target_speeds" in action:
            out["target_speeds"] = action["target_speeds"]
        return out
    if kind != "ContinuousAction":
        raise ValueError(f"{name}: action type must be ContinuousAction, got {kind!r}")
    lon = action.get("longitudinal", True)
    lat = action.get("lateral", True)
    if (lon, lat) != (scenario.longitudinal, scenario.lateral):
        raise ValueError(f"{name}: ContinuousAction(longitudinal={lon}, lateral={lat}) does not match "
                         f"action_mode={getattr(scenario, 'action_mode', None)!r}")
    return {}


def _action_mode_from_config(scenario: Scenario, config: dict) -> str | None:
    """The action mode an env_config's ``ContinuousAction`` asks for (None: the scenario's default)."""
    action = config.get("action")
    if scenario.discrete or not isinstance(action, dict):
        return None
    if action.get("type") == "MultiAgentAction":
        action = action.get("action_config", {})
    if action.get("type") != "ContinuousAction":
        return None
    from envs_jax.scenarios.continuous import action_mode

    return action_mode(action.get("longitudinal", True), action.get("lateral", True))


def _check_observation(name: str, obs: dict) -> None:
    if obs.get("type") == "MultiAgentObservation":
        obs = obs.get("observation_config", {})
    for key, expected in _EXPECTED_OBS.items():
        if key in obs and obs[key] != expected:
            raise ValueError(f"{name}: observation {key}={obs[key]!r} is not supported; "
                             f"the simulator implements {_EXPECTED_OBS}")
