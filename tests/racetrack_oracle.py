"""highway-env oracle of ``racetrack-v0`` with K controlled vehicles (its ``RacetrackEnv``).

highway-env runs its own task from the JAX initial state *injected*: every vehicle's
position, heading, speed and list position (controlled plain ``Vehicle`` s first, then the
``IDMVehicle`` s, whose lane-change timers highway-env computes itself and which are
checked against the JAX ones). After every simulation frame every vehicle is recorded;
after every step the observations, per-agent rewards, costs and terminations.

Per-agent outcomes: ``_reward(action)`` / ``_is_terminated`` read ``self.vehicle`` (the
first controlled vehicle); agent k's values are those functions evaluated with vehicle k
first and its own action (k = 0 with K = 1 is exactly what ``env.step`` returns, which is
checked). The cost is the authors' ``collision_cost * crashed + offroad_cost * off_road``
from highway-env's ``crashed`` and ``on_road``.

highway-env is imported in tests only.
"""

from __future__ import annotations

import numpy as np
from highway_env.envs.racetrack_env import RacetrackEnv
from highway_env.vehicle.kinematics import Vehicle

from tests.traffic_oracle import finish_records, multi_agent_config, record_frames
from tests.traffic_oracle import inject as inject_state


def oracle_config(controlled: int, observation: dict | None = None, action: dict | None = None, **extra) -> dict:
    """highway-env config of racetrack-v0 with ``controlled`` agents (multi-agent action/observation when > 1)."""
    obs = observation or dict(RacetrackEnv.default_config()["observation"])
    act = action or dict(RacetrackEnv.default_config()["action"])
    return multi_agent_config(controlled, obs, act, **extra)


def inject(env, init: dict, controlled: tuple) -> list:
    """Replace the vehicles of a reset ``env`` by the JAX initial state ``init`` (numpy, per slot), the
    controlled ones plain ``Vehicle`` s; returns highway-env's own lane-change timers of the IDM vehicles (slot
    order)."""
    return inject_state(env, init, controlled, vehicle_class=Vehicle, driver_draws=False)


def agent_outcomes(env, actions, collision_cost: float, offroad_cost: float) -> tuple:
    """Per-agent ``(_reward(a_k), _is_terminated, cost)`` with each controlled vehicle taken as ``env.vehicle``."""
    vehicles = list(env.controlled_vehicles)
    rewards, terms, costs = [], [], []
    try:
        for k, veh in enumerate(vehicles):
            env.controlled_vehicles = [veh] + vehicles[:k] + vehicles[k + 1:]
            rewards.append(env._reward(actions[k]))
            terms.append(bool(env._is_terminated()))
            costs.append(collision_cost * veh.crashed + offroad_cost * (not veh.on_road))
    finally:
        env.controlled_vehicles = vehicles
    return np.array(rewards), np.array(terms), np.array(costs)


def run_oracle(init: dict, controlled: tuple, actions, config: dict, collision_cost: float = 1.0,
               offroad_cost: float = 0.5, grid_ties: bool = True) -> dict:
    """Run ``actions`` (``[T, K, d]`` floats) from the injected state; records as documented in the module,
    and with an occupancy grid, ``ties[t][k]``: the :func:`tie_cells` of agent k's observation at step t."""
    env = RacetrackEnv(config=config)
    env.reset(seed=0)
    timers = inject(env, init, controlled)
    vehicles = list(env.road.vehicles)
    frames = record_frames(env, vehicles)
    grid = grid_ties and "OccupancyGrid" in str(config["observation"])

    def ties():
        if not grid:
            return []
        return [tie_cells(env, ego, [v.position for v in vehicles if v is not ego]) for ego in env.controlled_vehicles]

    obs0 = env.observation_type.observe()
    out = {"obs": [np.asarray(obs0)], "reward": [], "terminated": [], "truncated": [], "cost": [],
           "env_reward": [], "env_terminated": [], "timers": np.array(timers), "ties": [ties()]}
    k = len(controlled)
    for a in np.asarray(actions, dtype=np.float64):
        act = a[0] if k == 1 else tuple(a)
        obs, reward, terminated, truncated, _ = env.step(act)
        rewards, terms, costs = agent_outcomes(env, a, collision_cost, offroad_cost)
        out["obs"].append(np.asarray(obs))
        out["ties"].append(ties())
        out["reward"].append(rewards)
        out["terminated"].append(terms)
        out["cost"].append(costs)
        out["truncated"].append(truncated)
        out["env_reward"].append(reward)
        out["env_terminated"].append(terminated)
        if all(terms) or truncated:  # the JAX episode's ``done``
            break
    return finish_records(out, frames, ("obs", "reward", "terminated", "truncated", "cost", "env_reward",
                                        "env_terminated"), k)


def tie_cells(env, observer, others_xy, eps: float = 1e-9) -> set:
    """Grid cells of an ``OccupancyGrid`` observation whose content hangs on a rounding tie.

    A point (a lane waypoint of ``fill_road_layer_by_lanes`` or a vehicle in ``others_xy``)
    within ``eps`` of a cell edge, in the observer's frame, lands on either side depending on
    the last bit of the arithmetic: at a reset every vehicle sits exactly on its lane's centre
    line, so the waypoints of a straight lane through it lie on the edge ``y = 0``. Returns the
    cells on both sides of every such point, computed with highway-env's own lane objects.
    """
    obs_type = env.observation_type
    if hasattr(obs_type, "agents_observation_types"):
        obs_type = obs_type.agents_observation_types[0]
    size, step = obs_type.grid_size, obs_type.grid_step
    shape = obs_type.grid.shape[-2:]
    ox, oy = observer.position
    c, s = np.cos(observer.heading), np.sin(observer.heading)
    points = [np.asarray(p, float) for p in others_xy]
    spacing = np.amin(step)
    for tos in env.road.network.graph.values():
        for lanes in tos.values():
            for lane in lanes:
                origin, _ = lane.local_coordinates(observer.position)
                for w in np.arange(origin - 100, origin + 100, spacing).clip(0, lane.length):
                    points.append(lane.position(w, 0))
    out = set()
    for p in points:
        d = np.array([p[0] - ox, p[1] - oy])
        if obs_type.align_to_vehicle_axes:
            d = np.array([[c, s], [-s, c]]) @ d
        u = (d - size[:, 0]) / step
        lo, hi = np.floor(u - eps / step), np.floor(u + eps / step)
        if np.any(lo != hi):
            for i in {int(lo[0]), int(hi[0])}:
                for j in {int(lo[1]), int(hi[1])}:
                    if 0 <= i < shape[0] and 0 <= j < shape[1]:
                        out.add((i, j))
    return out


def lane_tie(network, lanes: dict, x, y, heading, a: int, b: int, tol: float = 1e-9) -> bool:
    """Whether highway-env's closest-lane distances of lanes ``a`` and ``b`` (global numbers) are tied at a pose
    (the outer g->h and h->i lanes are one circle between 165 and 170 degrees: round-off picks either)."""
    names = {v: key for key, v in lanes.items()}
    pos = np.array([x, y])
    da = network.get_lane(names[a]).distance_with_heading(pos, heading)
    db = network.get_lane(names[b]).distance_with_heading(pos, heading)
    return abs(da - db) <= tol


def oracle_sensitivity(init: dict, controlled: tuple, actions, config: dict) -> float:
    """How far highway-env moves *itself* when every initial x is nudged by one ulp: the largest position
    gap between the two oracle runs (chaotic cases: cars resting in exact contact after a crash, where
    whether a third car's impact is overwritten hangs on the last bit)."""
    base = run_oracle(init, controlled, actions, config, grid_ties=False)
    nudged = dict(init, x=np.nextafter(np.asarray(init["x"], np.float64), np.inf))
    moved = run_oracle(nudged, controlled, actions, config, grid_ties=False)
    n = min(len(base["frames"]["x"]), len(moved["frames"]["x"]))
    return float(max(np.abs(base["frames"][k][:n] - moved["frames"][k][:n]).max() for k in ("x", "y")))
