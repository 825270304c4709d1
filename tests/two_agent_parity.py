"""The authors' scenarios with K agents against their two-agent envs: the same actions on both, every step compared.

Used by ``tests/test_roundabout_agents.py`` and ``tests/test_racetrack_agents.py`` (K = 2 without traffic must
reproduce the two-agent env under x64).
"""

from __future__ import annotations

import functools

import jax
import numpy as np

import envs_jax

PARITY_TOL = 1e-9  # x64; the two programs compute the same expressions, so equality is expected
VALUES = ("obs", "x", "y", "heading", "speed", "reward", "cost")
FLAGS = ("crashed", "on_road", "terminated", "truncated", "done")


@functools.lru_cache(maxsize=None)
def episodes_fn(name: str, x64: bool, **kw):
    """Jitted, vmapped episodes of fixed length from ``reset(key(0))``: per-step agent state, rewards, costs, flags
    and observations (``x64`` keys the cache: the program depends on it)."""
    env = envs_jax.make(name, **kw)
    idx = np.asarray(getattr(env, "controlled", (0, 1)))

    def episode(actions):
        obs0, st0 = env.reset(jax.random.key(0))

        def body(st, action):
            obs, st, reward, cost, done, info = env._step_jit(jax.random.key(1), st, action, env.default_params)[:6]
            out = dict(obs=obs, x=st.x[idx], y=st.y[idx], heading=st.heading[idx], speed=st.speed[idx],
                       crashed=st.crashed[idx], on_road=st.on_road[idx], reward=reward, cost=cost,
                       terminated=info["terminated"], truncated=info["truncated"], done=done)
            return st, out

        _, out = jax.lax.scan(body, st0, actions)
        init = dict(obs=obs0, x=st0.x[idx], y=st0.y[idx], heading=st0.heading[idx], speed=st0.speed[idx])
        return init, out

    return env, jax.jit(jax.vmap(episode))


def compare(two: tuple, k_env: tuple, actions) -> tuple[list, dict]:
    """Run ``actions [episodes, steps, 2, ...]`` on the two-agent env ``two = (name, kwargs)`` and on ``k_env`` (the
    same form); every step up to the two-agent episode's end must agree. Returns the episode lengths and the
    two-agent record."""
    _, run_a = episodes_fn(two[0], True, **two[1])
    _, run_b = episodes_fn(k_env[0], True, **k_env[1])
    (init_a, out_a), (init_b, out_b) = jax.device_get(run_a(actions)), jax.device_get(run_b(actions))
    for key in init_a:  # both resets are deterministic: the same initial state without injection
        np.testing.assert_allclose(init_b[key], init_a[key], rtol=0, atol=PARITY_TOL, err_msg=key)
    steps = actions.shape[1]
    lengths = []
    for e in range(actions.shape[0]):
        done = np.asarray(out_a["done"][e])
        n = int(np.argmax(done)) + 1 if done.any() else steps
        lengths.append(n)
        for key in VALUES:
            np.testing.assert_allclose(out_b[key][e, :n], out_a[key][e, :n], rtol=0, atol=PARITY_TOL,
                                       err_msg=f"episode {e}: {key}")
        for key in FLAGS:
            np.testing.assert_array_equal(out_b[key][e, :n], out_a[key][e, :n], err_msg=f"episode {e}: {key}")
    return lengths, out_a
