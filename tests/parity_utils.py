"""JAX side of the parity suite: run an ``envs_jax`` episode under fixed actions and return the same
keys as ``tests.highway_oracle.run_oracle`` (state after every step and every substep)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

import envs_jax


@functools.lru_cache(maxsize=None)
def _episode_fn(name: str, x64: bool, overrides: tuple = ()):
    env = envs_jax.make(name, **dict(overrides))

    def episode(actions, params):
        obs0, st0 = env.reset(jax.random.key(0), params)

        def body(st, action):
            obs, st2, reward, cost, done, info, traj = env.step_substeps(jax.random.key(0), st, action, params)
            # The info flags of the authors' env (merge zeroes them once anyone crashed).
            if "leader_arrived" in info:
                arrived = jnp.stack([info["leader_arrived"], info["follower_arrived"]])
            else:
                arrived = info["arrived"]
            out = dict(obs=obs, reward=reward, cost=cost, done=done, terminated=info["terminated"],
                       truncated=info["truncated"], arrived=arrived, x=st2.x, y=st2.y,
                       heading=st2.heading, speed=st2.speed, crashed=st2.crashed, on_road=st2.on_road,
                       lane=st2.lane, target_lane=st2.target_lane, speed_index=st2.speed_index,
                       traj=traj, crash=info.get("crash", jnp.any(st2.crashed)))
            return st2, out

        _, out = jax.lax.scan(body, st0, actions)
        init = dict(obs=obs0, x=st0.x, y=st0.y, heading=st0.heading, speed=st0.speed, crashed=st0.crashed,
                    on_road=st0.on_road, lane=st0.lane, target_lane=st0.target_lane, speed_index=st0.speed_index)
        return init, out

    return env, jax.jit(episode)


def run_jax(name: str, actions, params=None, **overrides) -> dict:
    """Run ``actions`` (``[T, 2]`` or ``[T, 2, d]``) from reset; arrays cut at the episode's end."""
    x64 = jax.config.jax_enable_x64
    env, fn = _episode_fn(name, x64, tuple(sorted(overrides.items())))
    params = env.default_params if params is None else params
    actions = np.asarray(actions)
    actions = jnp.asarray(actions, jnp.int32 if env.discrete else None)
    init, out = jax.device_get(fn(actions, params))
    done = np.asarray(out["done"])
    length = int(np.argmax(done) + 1) if done.any() else len(done)
    res = {"length": length, "frames": env.frames}
    for k in ("x", "y", "heading", "speed", "crashed", "on_road", "lane", "target_lane", "speed_index", "obs"):
        res[k] = np.concatenate([np.asarray(init[k])[None], np.asarray(out[k])[:length]])
    for k in ("reward", "cost", "done", "terminated", "truncated", "arrived", "crash"):
        res[k] = np.asarray(out[k])[:length]
    # The authors' per-agent flag includes the time limit.
    res["terminated_authors"] = res["terminated"] | res["truncated"][:, None]
    for k, v in out["traj"].items():
        v = np.asarray(v)[:length]  # [T, frames, 2]
        res["sub_" + k] = v.reshape(-1, *v.shape[2:])
    return res


def first_event(flags) -> int:
    """Index of the first True along axis 0 (per column), -1 if none."""
    flags = np.asarray(flags, bool)
    idx = np.argmax(flags, axis=0)
    return np.where(flags.any(axis=0), idx, -1)
