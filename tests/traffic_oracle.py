"""highway-env oracle of the traffic tasks (``highway-v0``, ``highway-fast-v0``, ``merge-v0``, ``roundabout-v0``,
and ``merge-cavs-v0`` through tests/merge_cavs_oracle.py) with K controlled vehicles.

highway-env runs its own task (its ``HighwayEnv`` / ``HighwayEnvFast`` classes, its
``IDMVehicle`` drivers, its ``road.act`` / ``road.step`` order) from an initial state
*injected* from the JAX simulator: every vehicle's position, heading, speed and list
position, the drivers' randomised exponent ``DELTA`` and target speeds, the lane-change
timers (checked against highway-env's own formula), the controlled vehicles' target
speeds and the planned routes (checked against highway-env's own ``plan_route_to``).
After every simulation frame every vehicle is recorded; after every step the
observations, per-agent rewards and terminations.

Per-agent outcomes: highway-env's ``_reward`` / ``_is_terminated`` read
``self.vehicle`` (the first controlled vehicle); agent k's values are those
functions evaluated with vehicle k first and agent k's own action (with one agent,
exactly what ``env.step`` returns, which is checked).

highway-env is imported here only; it must never be imported outside ``tests/``.
"""

from __future__ import annotations

import contextlib
import types

import numpy as np
from highway_env.envs.highway_env import HighwayEnv, HighwayEnvFast
from highway_env.envs.merge_env import MergeEnv
from highway_env.envs.roundabout_env import RoundaboutEnv
from highway_env.vehicle.behavior import IDMVehicle

from tests.merge_cavs_oracle import MergeCavsOracle

CLASSES = {"highway-v0": HighwayEnv, "highway-fast-v0": HighwayEnvFast, "merge-v0": MergeEnv,
           "roundabout-v0": RoundaboutEnv, "merge-cavs-v0": MergeCavsOracle}


def multi_agent_config(controlled: int, observation: dict, action: dict, **extra) -> dict:
    """highway-env config with ``controlled`` agents: ``observation``/``action`` wrapped in highway-env's
    ``MultiAgentObservation``/``MultiAgentAction`` when there are several, then ``extra``."""
    cfg = {"controlled_vehicles": controlled}
    if controlled > 1:
        cfg["observation"] = {"type": "MultiAgentObservation", "observation_config": observation}
        cfg["action"] = {"type": "MultiAgentAction", "action_config": action}
    else:
        cfg["observation"] = observation
        cfg["action"] = action
    cfg.update(extra)
    return cfg


def oracle_config(name: str, controlled: int, observation: dict | None = None, **extra) -> dict:
    """highway-env config of a task with ``controlled`` agents (multi-agent action/observation when > 1)."""
    defaults = CLASSES[name].default_config()
    return multi_agent_config(controlled, observation or defaults["observation"], defaults["action"], **extra)


def lane_numbers(network) -> dict:
    """``(from, to, id)`` -> global lane number in ``graph`` iteration order (the JAX numbering)."""
    out = {}
    for f, tos in network.graph.items():
        for t, lanes in tos.items():
            for i in range(len(lanes)):
                out[(f, t, i)] = len(out)
    return out


def inject(env, init: dict, controlled: tuple, routes: dict | None = None, vehicle_class=None,
           driver_draws: bool = True) -> list:
    """Replace the vehicles of a reset ``env`` by the JAX initial state ``init`` (numpy, per slot).

    Controlled slots become ``vehicle_class`` (default: the action type's), the others ``IDMVehicle`` s, with the
    JAX drivers' ``DELTA`` and target speed when ``driver_draws``. ``routes``: slot -> planned route (list of
    ``(from, to, id or None)``); each is checked against highway-env's own ``plan_route_to`` its last node.
    Returns the lane-change timers highway-env computed itself for the IDM vehicles (slot order).
    """
    road = env.road
    vehicle_class = env.action_type.vehicle_class if vehicle_class is None else vehicle_class
    vehicles, ctrl, timers = [], [], []
    for i in np.nonzero(init["alive"])[0]:
        pos = [float(init["x"][i]), float(init["y"][i])]
        h, v = float(init["heading"][i]), float(init["speed"][i])
        if i in controlled:
            veh = vehicle_class(road, pos, h, v)
            ctrl.append(veh)
        else:
            veh = IDMVehicle(road, pos, h, v)
            if driver_draws:
                veh.DELTA = float(init["delta"][i])
                veh.target_speed = float(init["target_speed"][i])
            timers.append(veh.timer)
            if isinstance(env, HighwayEnvFast):
                veh.check_collisions = False
        if routes and routes.get(int(i)):
            route = [tuple(step) for step in routes[int(i)]]
            veh.plan_route_to(route[-1][1])
            assert veh.route == route, (i, veh.route, route)
        vehicles.append(veh)
    road.vehicles = vehicles
    env.controlled_vehicles = ctrl
    env.define_spaces()
    return timers


def record_frames(env, vehicles: list) -> list:
    """Hook ``env.road.step`` so that every simulation frame appends the state of ``vehicles`` (positions,
    headings, speeds, crashes, lane and target lane as JAX lane numbers; -1 for a vehicle without a target lane)
    to the returned list."""
    lanes = lane_numbers(env.road.network)
    frames = []

    def record():
        frames.append({
            "x": [v.position[0] for v in vehicles], "y": [v.position[1] for v in vehicles],
            "heading": [v.heading for v in vehicles], "speed": [v.speed for v in vehicles],
            "crashed": [v.crashed for v in vehicles],
            "lane": [lanes[(v.lane_index[0], v.lane_index[1], int(v.lane_index[2]))] for v in vehicles],
            "target_lane": [lanes[(v.target_lane_index[0], v.target_lane_index[1], int(v.target_lane_index[2]))]
                            if hasattr(v, "target_lane_index") else -1 for v in vehicles],
        })

    road_step = env.road.step

    def step_and_record(dt):
        road_step(dt)
        record()

    env.road.step = step_and_record
    return frames


def finish_records(out: dict, frames: list, keys, k: int) -> dict:
    """``out`` with the recorded ``frames`` stacked per field, the per-step lists ``keys`` as arrays and, for one
    agent, an agent axis added to the observations."""
    out["frames"] = {key: np.array([f[key] for f in frames]) for key in frames[0]} if frames else {}
    for key in keys:
        out[key] = np.array(out[key])
    if k == 1:
        out["obs"] = out["obs"][:, None]
    return out


def agent_outcomes(env, actions) -> tuple:
    """Per-agent ``(_reward, _is_terminated, _rewards)`` with each controlled vehicle taken as ``env.vehicle``
    and ``actions[k]`` (its own action) as the action."""
    vehicles = list(env.controlled_vehicles)
    rewards, terms, parts = [], [], []
    try:
        for k in range(len(vehicles)):
            env.controlled_vehicles = [vehicles[k]] + vehicles[:k] + vehicles[k + 1:]
            rewards.append(env._reward(actions[k]))
            terms.append(bool(env._is_terminated()))
            parts.append(env._rewards(actions[k]))
    finally:
        env.controlled_vehicles = vehicles
    return np.array(rewards), np.array(terms), parts


def run_oracle(name: str, init: dict, controlled: tuple, actions, config: dict, steps: int | None = None,
               routes: dict | None = None) -> dict:
    """Run ``actions`` (``[T, K]`` ints) from the injected state; records as documented in the module."""
    env = CLASSES[name](config=config)
    env.reset(seed=0)
    timers = inject(env, init, controlled, routes)
    frames = record_frames(env, list(env.road.vehicles))
    obs0 = env.observation_type.observe()
    out = {"obs": [np.asarray(obs0)], "reward": [], "terminated": [], "truncated": [], "env_reward": [],
           "env_terminated": [], "parts": [], "timers": np.array(timers)}
    k = len(controlled)
    for t, a in enumerate(np.asarray(actions)):
        if steps is not None and t >= steps:
            break
        act = int(a[0]) if k == 1 else tuple(int(u) for u in a)
        obs, reward, terminated, truncated, _ = env.step(act)
        rewards, terms, parts = agent_outcomes(env, [int(u) for u in a])
        out["obs"].append(np.asarray(obs))
        out["reward"].append(rewards)
        out["terminated"].append(terms)
        out["truncated"].append(truncated)
        out["env_reward"].append(reward)
        out["env_terminated"].append(terminated)
        out["parts"].append(parts)
    return finish_records(out, frames, ("obs", "reward", "terminated", "truncated", "env_reward", "env_terminated"), k)


@contextlib.contextmanager
def arcsin_one_ulp_off(direction: int):
    """highway-env's steering controller with its ``arcsin`` one ulp up (``direction`` 1) or down (-1); 0 leaves it
    exact.

    XLA's float64 arcsin and arctan2 differ from the C library's by an ulp on some inputs; near zero speed
    the controller divides by ``not_zero(speed)`` and amplifies such differences without bound, so how far
    highway-env moves *itself* under this nudge bounds what parity can mean there (docs/parity.md)."""
    if not direction:
        yield
        return
    import highway_env.vehicle.controller as controller

    class Shifted(types.ModuleType):
        def __getattr__(self, attr):
            return getattr(np, attr)

    shifted = Shifted("numpy_one_ulp")
    shifted.arcsin = lambda v: np.nextafter(np.arcsin(v), direction * np.inf)
    controller.np = shifted
    try:
        yield
    finally:
        controller.np = np
