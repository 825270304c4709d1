"""The simulators measured beside envs_jax on the traffic tasks: highway-env, EnvPool's C++ port and HighJax.

Each is stepped with uniform random actions and auto-reset, and each can describe its task (vehicles at reset,
frequencies, duration, observation and action shapes) so that ``env_throughput.py`` checks that the same task is
being compared. EnvPool and HighJax are optional: :func:`envpool_tasks` and :func:`highjax_env` say why one is
missing instead of raising.

* highway-env: ``gymnasium.make(task)`` after ``import highway_env``, one environment in this process.
* EnvPool (``pip install envpool``): ``envpool.make_gymnasium(task, num_envs, batch_size, num_threads)``; with
  ``batch_size < num_envs`` it runs asynchronously (``send``/``recv``). The step after an episode's end is
  EnvPool's reset of that environment (``info["elapsed_step"] == 0``) and is not counted as a step.
* HighJax (``pip install highjax``; it declares Python >= 3.14 but runs on 3.11, so
  ``pip install --no-deps --ignore-requires-python highjax``): its ``highjax-v0`` is highway-env's highway-v0
  (4 lanes, 50 other vehicles, 15 Hz, one decision per second, 40 s), single agent, with its own auto-reset.
"""

from __future__ import annotations

import os
import statistics
import time

import numpy as np

HIGHJAX_TASKS = {"highway-v0": "highjax-v0"}


def _space(space) -> dict:
    if hasattr(space, "spaces"):  # one space per controlled vehicle (highway-env's multi-agent tasks): alike
        return _space(space.spaces[0])
    if hasattr(space, "n"):
        return {"actions": int(space.n)}
    return {"action_shape": list(space.shape)}


def _obs_shape(space) -> list[int]:
    """An observation space's shape; a tuple of one space per controlled vehicle as ``[K, ...]``."""
    if hasattr(space, "spaces"):
        return [len(space.spaces)] + list(space.spaces[0].shape)
    return list(space.shape)


def _random_action(space, rng, batch=None):
    if hasattr(space, "spaces"):
        return tuple(_random_action(s, rng, batch) for s in space.spaces)
    if hasattr(space, "n"):
        return rng.integers(0, space.n, batch) if batch is not None else int(rng.integers(0, space.n))
    shape = space.shape if batch is None else (batch,) + tuple(space.shape)
    return rng.uniform(-1.0, 1.0, shape).astype(np.float32)


# ----------------------------------------------------------------------------------------------
# highway-env

def highway_env_task(task: str):
    """highway-env's own environment for ``task`` (its default config)."""
    import gymnasium
    import highway_env  # noqa: F401  (registers the task ids)

    return gymnasium.make(task)


def describe_highway_env(task: str) -> dict:
    from tests.intersection_oracle import idm_constants_kept  # the intersection's resets change IDMVehicle

    with idm_constants_kept():
        env = highway_env_task(task)
        env.reset(seed=0)
    cfg = env.unwrapped.config
    return {"vehicles": len(env.unwrapped.road.vehicles), "controlled": len(env.unwrapped.controlled_vehicles),
            "simulation_frequency": cfg["simulation_frequency"], "policy_frequency": cfg["policy_frequency"],
            "duration": cfg.get("duration"), "obs_shape": _obs_shape(env.observation_space),
            **_space(env.action_space)}


def measure_highway_env(task: str, seconds: float, repeats: int = 3) -> dict:
    """Steps per second of highway-env on ``task``: median over ``repeats`` blocks of ``seconds / repeats``."""
    from tests.intersection_oracle import idm_constants_kept  # the intersection's resets change IDMVehicle

    rates, steps_total = [], 0
    with idm_constants_kept():
        env = highway_env_task(task)
        rng = np.random.default_rng(0)
        env.reset(seed=0)
        for _ in range(repeats):
            steps, t0 = 0, time.perf_counter()
            while time.perf_counter() - t0 < seconds / repeats or steps == 0:
                _, _, terminated, truncated, _ = env.step(_random_action(env.action_space, rng))
                steps += 1
                if terminated or truncated:
                    env.reset()
            rates.append(steps / (time.perf_counter() - t0))
            steps_total += steps
    return {"steps_per_s": statistics.median(rates), "steps": steps_total}


# ----------------------------------------------------------------------------------------------
# EnvPool

def envpool_tasks() -> tuple[set, str]:
    """The task ids EnvPool registers, and a note (its version, or why it is unavailable)."""
    try:
        import envpool
    except ImportError as err:
        return set(), f"envpool not importable ({err}); pip install envpool"
    return set(envpool.list_all_envs()), f"envpool {envpool.__version__}"


def describe_envpool(task: str) -> dict:
    import envpool

    env = envpool.make_gymnasium(task, num_envs=1, batch_size=1, num_threads=1, seed=0)
    env.reset()
    debug = env.debug_states()[0]
    cfg = env.spec.config
    players = int(getattr(cfg, "max_num_players", 1))
    shape = list(env.observation_space.shape)
    return {"vehicles": len(debug.vehicles), "controlled": players,
            "simulation_frequency": int(debug.simulation_frequency), "policy_frequency": int(debug.policy_frequency),
            "duration": getattr(cfg, "duration", None), "obs_shape": [players] + shape if players > 1 else shape,
            **_space(env.action_space)}


def measure_envpool(task: str, num_envs: int, batch_size: int, seconds: float, repeats: int = 3,
                    num_threads: int | None = None, **config) -> dict:
    """Steps per second of EnvPool on ``task``: ``num_envs`` environments on ``num_threads`` threads (default:
    all cores), ``batch_size`` of them per call (asynchronous when smaller), median over ``repeats`` blocks.
    ``config``: task keys of EnvPool's spec (e.g. ``vehicles_count``)."""
    import envpool

    threads = num_threads or os.cpu_count()
    env = envpool.make_gymnasium(task, num_envs=num_envs, batch_size=batch_size, num_threads=threads, seed=0,
                                 **config)
    space = env.action_space
    players = int(getattr(env.spec.config, "max_num_players", 1))  # multi-player tasks: one action per player
    rng = np.random.default_rng(0)
    sync = batch_size == num_envs
    if sync:
        env.reset()
    else:
        env.async_reset()
    rates = []
    for _ in range(repeats):
        steps, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds / repeats or steps == 0:
            if sync:
                _, _, _, _, info = env.step(_random_action(space, rng, num_envs * players))
            else:
                _, _, _, _, info = env.recv()
                env.send(_random_action(space, rng, batch_size * players), info["env_id"])
            steps += int(np.count_nonzero(np.asarray(info["elapsed_step"]) > 0))
        rates.append(steps / (time.perf_counter() - t0))
    env.close()
    return {"num_envs": num_envs, "batch_size": batch_size, "num_threads": threads,
            "steps_per_s": statistics.median(rates)}


# ----------------------------------------------------------------------------------------------
# HighJax

def highjax_env(task: str):
    """``(env, params)`` of HighJax for ``task``, or ``(None, why)``."""
    if task not in HIGHJAX_TASKS:
        return None, f"HighJax has no {task}"
    try:
        import highjax
    except ImportError as err:
        return None, (f"highjax not importable ({err}); pip install --no-deps --ignore-requires-python highjax")
    env, params = highjax.make(HIGHJAX_TASKS[task])
    return (env, params), f"highjax {highjax.__version__}"


def describe_highjax(env, params) -> dict:
    return {"vehicles": int(env.n_npcs) + 1, "controlled": 1,
            "simulation_frequency": round(1.0 / float(params.seconds_per_sub_t)),
            "policy_frequency": round(1.0 / float(params.seconds_per_t)), "duration": float(params.duration),
            "obs_shape": list(env.observation_shape), "actions": int(env.num_actions)}


class HighJaxAdapter:
    """HighJax behind envs_jax's step signature (``obs, state, reward, cost, done, info``), for
    ``env_throughput.jax_runner``; HighJax resets finished episodes itself."""

    discrete = True

    def __init__(self, env, params):
        self.env = env
        self.default_params = params
        self.num_actions = int(env.num_actions)
        self.action_shape = ()

    def reset(self, key, params=None):
        return self.env.reset(key, params)

    def step(self, key, state, action, params=None):
        obs, state, reward, done, info = self.env.step(key, state, action, params)
        return obs, state, reward, reward * 0, done, info
