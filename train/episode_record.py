"""One episode of a policy recorded frame by frame for drawing: every simulation frame of every vehicle (the agents
and any background traffic), in one jitted ``lax.scan`` (``env.step_substeps``); simple reference policies.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.time_limit import step_limit

__all__ = ["POLICIES", "simple_policy", "max_decisions", "simulate"]


POLICIES = ("random", "idle")
# Per-frame vehicle fields every environment's ``step_substeps`` records.
FIELDS = ("x", "y", "heading", "speed", "crashed")


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

    Returns ``x, y, heading, speed, crashed, alive`` as ``[1 + n * frames, V]`` (the reset state, then every
    simulation frame of the ``n`` decisions until ``done``; V vehicles: the two agents of the authors' scenarios,
    every slot of a traffic task), ``action`` ``[n, ...]``, ``reward``, ``cost`` ``[n, K]``, ``done`` ``[n]``,
    ``n`` and ``controlled`` (the agents' slot indices, leader first). A slot is drawn during a decision when it
    was alive as the decision began: vehicles removed at its end are still shown driving, new ones appear with
    the next decision.
    """
    T = max_decisions(env, params) if max_steps is None else int(max_steps)
    k_reset, k_run = jax.random.split(key)

    controlled = tuple(int(i) for i in getattr(env, "controlled", range(env.num_agents)))

    def pose(st):
        out = {k: getattr(st, k) for k in FIELDS}
        out["alive"] = getattr(st, "alive", jnp.ones(st.x.shape, bool))  # the authors' two cars are always there
        return out

    @jax.jit
    def run(k_reset, k_run):
        obs, state = env.reset(k_reset, params)

        def body(carry, k):
            obs, state, over = carry
            k_act, k_step = jax.random.split(k)
            action = policy(k_act, obs)
            obs2, state2, reward, cost, done, info, traj = env.step_substeps(k_step, state, action, params)
            frames = {k: traj[k] for k in FIELDS}
            frames["alive"] = jnp.broadcast_to(pose(state)["alive"], traj["x"].shape)
            out = dict(action=action, reward=reward, cost=cost, done=done, live=~over, frames=frames)
            return (obs2, state2, over | done), out

        _, outs = jax.lax.scan(body, (obs, state, jnp.zeros((), bool)), jax.random.split(k_run, T))
        return pose(state), outs

    first, outs = jax.device_get(run(k_reset, k_run))
    n = int(np.sum(outs["live"]))
    rec = {}
    for k, v in first.items():
        frames = np.asarray(outs["frames"][k])[:n]  # [n, F, V]
        rec[k] = np.concatenate([np.asarray(v)[None], frames.reshape((-1,) + frames.shape[2:])])
    for k in ("action", "reward", "cost", "done"):
        rec[k] = np.asarray(outs[k])[:n]
    rec["controlled"] = controlled
    rec["n"] = n
    rec["frames_per_decision"] = env.frames
    return rec
