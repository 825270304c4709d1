"""JAX side of the intersection parity suite: an episode under fixed actions with its draws, per frame."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

import envs_jax

DRAW_KEYS = ("u", "route", "z_position", "z_speed", "u_delta")


_CACHE: dict = {}


def episode_fn(name: str, x64: bool, overrides: dict):
    """The environment and a jitted ``(key, actions) -> (draws, events, obs0, state0, per-step outputs)``."""
    cache_key = (name, x64, repr(sorted(overrides.items())))
    if cache_key not in _CACHE:
        _CACHE[cache_key] = _episode_fn(name, overrides)
    return _CACHE[cache_key]


def _episode_fn(name: str, overrides: dict):
    env = envs_jax.make(name, **overrides)

    def episode(key, actions):
        params = env.default_params
        key_init, key_obs = jax.random.split(key)
        draws = env.task.reset_draws(key_init, params)
        obs0, st0, events = env.reset_from_draws(draws, params, key_obs, events=True)

        def body(st, inp):
            k, action = inp
            obs, st2, reward, cost, done, info, traj = env.step_substeps(k, st, action, params)
            out = dict(obs=obs, reward=reward, cost=cost, done=done, terminated=info["terminated"],
                       truncated=info["truncated"], env_terminated=info["env_terminated"], traj=traj,
                       alive=st2.alive, spawn=info["spawn"], draws=info["spawn_draws"],
                       skipped=info["spawn_skipped"])
            return st2, out

        keys = jax.random.split(jax.random.fold_in(key, 1), actions.shape[0])
        _, out = jax.lax.scan(body, st0, (keys, actions))
        return draws, events, obs0, st0, out

    return env, jax.jit(episode)


def attempt_records(draws, events) -> list:
    """Spawn attempts as oracle records: the draws, the slot taken (-1: none) and whether the pool was full."""
    n = np.asarray(events["slot"]).shape[0]
    return [dict({k: np.asarray(draws[k][i]) for k in DRAW_KEYS}, slot=int(events["slot"][i]),
                 pool_full=bool(events["pool_full"][i]), spawned=bool(events["spawned"][i])) for i in range(n)]


def reset_records(res) -> list:
    """The reset's attempts (initial ones, then the challenger) as oracle records."""
    draws, events = res["draws"], res["events"]
    recs = []
    if events["initial"] is not None:
        recs += attempt_records(draws["initial"], events["initial"])
    one = {k: np.asarray(v)[None] for k, v in events["challenger"].items()}
    return recs + attempt_records(draws["challenger"], one)


def step_records(res) -> list:
    return attempt_records(res["step_draws"], res["spawn"])


def run_jax(name: str, seed: int, actions, **overrides) -> dict:
    env, fn = episode_fn(name, bool(jax.config.jax_enable_x64), overrides)
    dtype = jnp.int32 if env.discrete else jnp.float64 if jax.config.jax_enable_x64 else jnp.float32
    draws, events, obs0, st0, out = jax.device_get(fn(jax.random.key(seed), jnp.asarray(actions, dtype)))
    done = np.asarray(out["done"])
    length = int(np.argmax(done) + 1) if done.any() else len(done)
    res = {"env": env, "draws": draws, "events": events, "st0": st0, "length": length,
           "obs": np.concatenate([np.asarray(obs0)[None], np.asarray(out["obs"])[:length]])}
    for k in ("reward", "cost", "done", "terminated", "truncated", "env_terminated", "alive", "skipped"):
        res[k] = np.asarray(out[k])[:length]
    res["spawn"] = {k: np.asarray(v)[:length] for k, v in out["spawn"].items()}
    res["step_draws"] = {k: np.asarray(v)[:length] for k, v in out["draws"].items()}
    frames = {}
    for k in out["traj"]:  # the fields of env._record
        v = np.asarray(out["traj"][k])[:length]
        frames[k] = v.reshape(-1, v.shape[-1])
    res["frames"] = frames
    return res
