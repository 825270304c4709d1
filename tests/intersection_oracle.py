"""highway-env oracle of ``intersection-v0`` / ``intersection-multi-agent-v0`` with the JAX episode's draws injected.

highway-env runs its own ``IntersectionEnv`` (``MultiAgentIntersectionEnv`` for K > 1):
its ``_make_vehicles`` (spawns, warm-up, challenger, agents), its ``RegulatedRoad``,
its ``_clear_vehicles`` and ``_spawn_vehicle``; only its random generator is replaced
by :class:`ScriptedRandom`, which answers each ``uniform`` / ``choice`` / ``normal`` /
``integers`` call with the number the JAX episode drew for it. Each vehicle is
tagged with the JAX slot it occupies (the agents: 0..K-1; a spawn: the slot the JAX
episode gave it), so every alive vehicle is compared after every simulation frame.
An attempt the JAX pool had no slot for is removed again right after highway-env
added it (the deliberately small pool test).

highway-env is imported here only; it must never be imported outside ``tests/``.
"""

from __future__ import annotations

import contextlib

import numpy as np
from highway_env.envs.intersection_env import ContinuousIntersectionEnv, IntersectionEnv, MultiAgentIntersectionEnv
from highway_env.vehicle.behavior import IDMVehicle

from tests.traffic_oracle import lane_numbers

IDM_ATTRS = ("DISTANCE_WANTED", "COMFORT_ACC_MAX", "COMFORT_ACC_MIN")


@contextlib.contextmanager
def idm_constants_kept():
    """Put back the IDM constants that highway-env's intersection assigns on the ``IDMVehicle`` class at every
    reset (``IDM_ATTRS``): otherwise every highway-env task run later in the process drives with them."""
    saved = {a: getattr(IDMVehicle, a) for a in IDM_ATTRS}
    try:
        yield
    finally:
        for a, v in saved.items():
            setattr(IDMVehicle, a, v)


class ScriptedRandom:
    """A stand-in for ``env.np_random`` that replays the JAX draws in highway-env's call order."""

    def __init__(self, attempts: list, z_ego, destination):
        self.attempts = list(attempts)
        self.next = 0
        self.current = None
        self.calls = {}
        self.z_ego = list(np.asarray(z_ego, np.float64))
        self.destination = list(np.asarray(destination))

    def begin(self):
        rec = self.attempts[self.next]
        self.next += 1
        self.current = rec
        self.calls = {"uniform": 0, "normal": 0}
        return rec

    def end(self):
        self.current = None

    def uniform(self, low=0.0, high=1.0, size=None):
        assert size is None and self.current is not None
        n = self.calls["uniform"]
        self.calls["uniform"] += 1
        return low + (high - low) * float(self.current["u"] if n == 0 else self.current["u_delta"])

    def choice(self, a, size=None, replace=True):
        assert list(a) == [0, 1, 2, 3] and size == 2 and not replace
        return np.array(self.current["route"], dtype=np.int64)

    def normal(self, loc=0.0, scale=1.0, size=None):
        assert size is None
        if self.current is None:  # an agent's start offset
            return loc + scale * self.z_ego.pop(0)
        n = self.calls["normal"]
        self.calls["normal"] += 1
        return loc + scale * float(self.current["z_position"] if n == 0 else self.current["z_speed"])

    def integers(self, low, high=None, size=None):
        assert (low, high, size) == (1, 4, None) and self.current is None
        return int(self.destination.pop(0))


def classes(k: int, continuous: bool = False):
    """highway-env's class of the task (``ContinuousIntersectionEnv`` for ``intersection-v1``, any K)."""
    base = ContinuousIntersectionEnv if continuous else IntersectionEnv if k == 1 else MultiAgentIntersectionEnv

    class Scripted(base):
        script = None  # set on the instance before the scripted reset

        def _reset(self):
            if self.script is not None:
                self.np_random = self.script
            super()._reset()

        def _spawn_vehicle(self, *args, **kwargs):
            if self.script is None:  # the constructor's own reset
                return super()._spawn_vehicle(*args, **kwargs)
            rec = self.script.begin()
            try:
                vehicle = super()._spawn_vehicle(*args, **kwargs)
            finally:
                self.script.end()
            if vehicle is not None and rec.get("pool_full", False):
                self.road.vehicles.remove(vehicle)
                self.pool_skips.append(self.script.next - 1)
                vehicle = None
            if vehicle is not None:
                vehicle.slot = int(rec["slot"])
            self.spawn_log.append(vehicle is not None)
            return vehicle

    return Scripted


def oracle_config(k: int, **extra) -> dict:
    cfg = {"controlled_vehicles": k}
    cfg.update(extra)
    return cfg


def run_oracle(k: int, attempts_reset: list, z_ego, destination, step_attempts: list, actions, config: dict,
               continuous: bool = False) -> dict:
    """An episode of highway-env's intersection with the JAX draws; records as in the module docstring.

    ``attempts_reset``: the reset's spawn attempts (initial ones, then the challenger), each a dict
    ``u, route, z_position, z_speed, u_delta, slot`` (``slot`` -1: not spawned in JAX) and optionally
    ``pool_full``; ``step_attempts``: one such dict per step. ``continuous``: ``intersection-v1``
    (``actions`` ``[T, K, d]`` floats; the agents' lateral speed and yaw rate are recorded too, 0 for
    vehicles without them, as their missing target speed).
    """
    with idm_constants_kept():
        env = classes(k, continuous)(config=config)
        env.script = ScriptedRandom(list(attempts_reset) + list(step_attempts), z_ego, destination)
        env.spawn_log, env.pool_skips = [], []
        env.reset(seed=0)
        assert env.script.next == len(attempts_reset)
        for i, v in enumerate(env.controlled_vehicles):
            v.slot = i
        lanes = lane_numbers(env.road.network)
        frames = []

        def snapshot():
            vs = env.road.vehicles
            return {"slot": [v.slot for v in vs], "x": [v.position[0] for v in vs], "y": [v.position[1] for v in vs],
                    "heading": [v.heading for v in vs], "speed": [v.speed for v in vs],
                    "crashed": [v.crashed for v in vs],
                    "lane": [lanes[(v.lane_index[0], v.lane_index[1], int(v.lane_index[2]))] for v in vs],
                    "yielding": [bool(getattr(v, "is_yielding", False)) for v in vs],
                    "target_speed": [getattr(v, "target_speed", 0.0) for v in vs],
                    "lateral_speed": [getattr(v, "lateral_speed", 0.0) for v in vs],
                    "yaw_rate": [getattr(v, "yaw_rate", 0.0) for v in vs]}

        road_step = env.road.step

        def step_and_record(dt):
            road_step(dt)
            frames.append(snapshot())

        env.road.step = step_and_record
        out = {"init": snapshot(), "init_spawns": list(env.spawn_log),
               "obs": [np.asarray(env.observation_type.observe())],
               "reward": [], "terminated": [], "env_terminated": [], "truncated": [], "after_step": [],
               "env_reward": []}
        for a in np.asarray(actions):
            if continuous:
                act = np.asarray(a[0], np.float64) if k == 1 else tuple(np.asarray(u, np.float64) for u in a)
            else:
                act = int(a[0]) if k == 1 else tuple(int(u) for u in a)
            obs, reward, terminated, truncated, info = env.step(act)
            out["obs"].append(np.asarray(obs))
            out["reward"].append([env._agent_reward(act, v) for v in env.controlled_vehicles])
            out["terminated"].append([env._agent_is_terminal(v) for v in env.controlled_vehicles])
            out["env_terminated"].append(terminated)
            out["truncated"].append(truncated)
            out["env_reward"].append(reward)
            out["after_step"].append(sorted(v.slot for v in env.road.vehicles))
        out["frames"] = frames
        out["spawns"] = list(env.spawn_log)
        out["pool_skips"] = list(env.pool_skips)
        out["max_vehicles"] = max([len(f["slot"]) for f in frames] + [len(out["init"]["slot"])])
        if k == 1:
            out["obs"] = [o[None] for o in out["obs"]]
        out["obs"] = np.array(out["obs"])
        for key in ("reward", "terminated", "env_terminated", "truncated", "env_reward"):
            out[key] = np.array(out[key])
        return out
