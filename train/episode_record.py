"""One episode of a policy recorded frame by frame for drawing: every simulation frame of every vehicle, in one
jitted ``lax.scan`` (``env.step_substeps``); simple reference policies.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.time_limit import step_limit

__all__ = ["POLICIES", "simple_policy", "max_decisions", "simulate"]


POLICIES = ("random", "idle")


def simple_policy(env, name: str) -> Callable:
    """``(key, obs) -> action``: ``random`` (uniform) or ``idle`` (IDLE meta-action / zero continuous action)."""
    from envs_jax.wrappers import random_actions

    if name == "random":
        return random_actions(env)
    if name == "idle":
        if env.discrete:
            return lambda key, obs: jnp.ones(env.action_shape, jnp.int32)  # 1 = IDLE
        return lambda key, obs: jnp.zeros(env.action_shape, jnp.float32)
    raise ValueError(f"unknown policy {name!r}; choose one of {', '.join(POLICIES)} (or pass --checkpoint RUN_DIR)")


def max_decisions(env, params) -> int:
    """The time limit in policy steps: ``ceil(duration * policy_frequency)`` (:mod:`envs_jax.time_limit`)."""
    return int(step_limit(float(params.duration), env.policy_frequency))


def simulate(env, params, policy: Callable, key, max_steps: int | None = None) -> dict:
    """One episode from ``reset(split(key)[0])``, in one jitted scan; numpy arrays on return.

    Returns ``x, y, heading, speed, crashed, on_road`` as ``[1 + n * frames, 2]`` (the reset state, then every
    simulation frame of the ``n`` decisions until ``done``), ``action`` ``[n, ...]``, ``reward``, ``cost``
    ``[n, 2]``, ``done`` ``[n]`` and ``n``.
    """
    T = max_decisions(env, params) if max_steps is None else int(max_steps)
    k_reset, k_run = jax.random.split(key)

    @jax.jit
    def run(k_reset, k_run):
        obs, state = env.reset(k_reset, params)

        def body(carry, k):
            obs, state, over = carry
            k_act, k_step = jax.random.split(k)
            action = policy(k_act, obs)
            obs2, state2, reward, cost, done, info, traj = env.step_substeps(k_step, state, action, params)
            out = dict(action=action, reward=reward, cost=cost, done=done, live=~over,
                       frames={k: traj[k] for k in ("x", "y", "heading", "speed", "crashed", "on_road")})
            return (obs2, state2, over | done), out

        _, outs = jax.lax.scan(body, (obs, state, jnp.zeros((), bool)), jax.random.split(k_run, T))
        first = {"x": state.x, "y": state.y, "heading": state.heading, "speed": state.speed,
                 "crashed": state.crashed, "on_road": state.on_road}
        return first, outs

    first, outs = jax.device_get(run(k_reset, k_run))
    n = int(np.sum(outs["live"]))
    rec = {}
    for k, v in first.items():
        frames = np.asarray(outs["frames"][k])[:n]  # [n, F, 2]
        rec[k] = np.concatenate([np.asarray(v)[None], frames.reshape((-1,) + frames.shape[2:])])
    for k in ("action", "reward", "cost", "done"):
        rec[k] = np.asarray(outs[k])[:n]
    rec["n"] = n
    rec["frames_per_decision"] = env.frames
    return rec
