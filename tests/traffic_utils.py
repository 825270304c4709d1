"""JAX side of the traffic parity suite: an episode of a traffic task under fixed actions, recorded per frame."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

import envs_jax

FRAME_KEYS = ("x", "y", "heading", "speed", "crashed", "lane", "target_lane")


@functools.lru_cache(maxsize=None)
def episode_fn(name: str, x64: bool, overrides: tuple = ()):
    """The environment and a jitted ``(key, actions) -> (init, per-step outputs)`` for it."""
    env = envs_jax.make(name, **dict(overrides))

    def episode(key, actions):
        params = env.default_params
        obs0, st0 = env.reset(key, params)

        def body(st, inp):
            k, action = inp
            obs, st2, reward, cost, done, info, traj = env.step_substeps(k, st, action, params)
            out = dict(obs=obs, reward=reward, cost=cost, done=done, terminated=info["terminated"],
                       truncated=info["truncated"], traj=traj)
            return st2, out

        keys = jax.random.split(jax.random.fold_in(key, 1), actions.shape[0])
        _, out = jax.lax.scan(body, st0, (keys, actions))
        return obs0, st0, out

    return env, jax.jit(episode)


def run_jax(name: str, seed: int, actions, **overrides) -> dict:
    """An episode from ``reset(key(seed))``: the initial state (numpy), per-step and per-frame records,
    cut at the first ``done``."""
    env, fn = episode_fn(name, bool(jax.config.jax_enable_x64), tuple(sorted(overrides.items())))
    obs0, st0, out = jax.device_get(fn(jax.random.key(seed), jnp.asarray(actions, jnp.int32)))
    done = np.asarray(out["done"])
    length = int(np.argmax(done) + 1) if done.any() else len(done)
    init = {k: np.asarray(getattr(st0, k)) for k in ("x", "y", "heading", "speed", "alive", "delta", "timer",
                                                      "target_speed", "lane", "target_lane", "route_roads",
                                                      "route_ids", "route_len")}
    res = {"env": env, "init": init, "length": length, "obs": np.concatenate([np.asarray(obs0)[None],
                                                                             np.asarray(out["obs"])[:length]])}
    for k in ("reward", "cost", "done", "terminated", "truncated"):
        res[k] = np.asarray(out[k])[:length]
    frames = {}
    for k in FRAME_KEYS:
        v = np.asarray(out["traj"][k])[:length]  # [T, frames, V]
        frames[k] = v.reshape(-1, v.shape[-1])
    res["frames"] = frames
    return res
