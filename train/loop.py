"""The compiled training loops' shared parts, and the off-policy loop (PureJaxRL style).

``make_train(config)`` returns a :class:`Trainer` for ``config["algo"]`` (built by the algorithm's
:class:`train.config.AlgoSpec`). Its functions are pure and per seed; vmap them over seeds:

* ``init(key) -> state``: a pytree with at least ``agent`` (the learner's state, used for evaluation).
* ``run_chunk(state, start_iter) -> (state, metrics)``: ``chunk_iters`` loop iterations in one compiled program.
  One iteration steps every one of the ``num_envs`` environments once. ``metrics["episode"]`` holds
  :func:`jaxsmarl.metrics.episode_record` s shaped ``[chunk_iters, num_envs]``; ``metrics["explore"]``
  (optional, ``[chunk_iters, k]``) the exploration parameters shown in the progress line; ``metrics["update"]``
  (optional) the learner's diagnostics, ``[updates, ...]``, and ``metrics["updated"]`` (optional, bool
  ``[updates]``) which of those entries are real updates (the off-policy warm-up records zeros).
  ``start_iter`` is unbatched (``in_axes=None``).
* ``train(key) -> (state, metrics)``: ``init`` + every chunk, one pure function: ``jit(vmap(train))(keys)``.
* ``evaluate(agent_state, key) -> records``: ``eval_episodes`` greedy episodes (vmapped); see :func:`make_evaluate`.

The host-side driver (:mod:`train.run`) calls ``init`` and ``run_chunk`` itself so it can log and checkpoint
between chunks; because it runs the very same compiled chunk, a resumed run is bit-identical.

The off-policy loop (:func:`make_offpolicy_train`, CSQ and the MADDPG family): one iteration = act in every env,
step the auto-resetting envs, store the transitions (with the pre-reset observation as ``s'`` and per-agent
``terminated``), then ``updates_per_step`` gradient updates once ``warmup`` transitions are stored (Algorithm 1's
inner loop); warm-up gating is a real branch, not a select, since the iteration index is unbatched. Its agent
provides ``init(key)``, ``exploration(env_step)`` (a pytree: CSQ's per-agent epsilon, MADDPG's noise scales),
``act(state, obs, key, explore)``, ``greedy_act(state, obs)``, ``update(state, batch, key, explore) -> (state,
info)``, ``transition_example()`` and ``Transition``; the config provides ``warmup``, ``batch_size``,
``updates_per_step`` and ``buffer_size``.
"""

from __future__ import annotations

import functools
import math
from typing import Any, Callable, NamedTuple

import flax.struct
import jax
import jax.numpy as jnp

from jaxsmarl import buffers, metrics

__all__ = ["RunnerState", "Trainer", "make_env", "make_train", "make_offpolicy_train", "make_evaluate",
           "make_train_fn", "seed_keys", "episode_step_limit", "with_matmul_precision"]


@flax.struct.dataclass
class RunnerState:
    agent: Any
    buffer: buffers.BufferState
    env_state: Any  # [num_envs, ...]
    obs: jax.Array  # [num_envs, n_agents, obs_dim]
    key: jax.Array
    iteration: jax.Array  # int32 loop iterations done


class Trainer(NamedTuple):
    config: dict
    env: Any
    agent: Any
    init: Callable
    run_chunk: Callable  # chunk_iters iterations
    run_tail: Callable | None  # the last, shorter chunk when total_iters % chunk_iters != 0
    train: Callable
    evaluate: Callable
    total_iters: int
    chunk_iters: int
    n_chunks: int  # including the tail chunk
    # Run the seeds of a device one after another (lax.map) instead of batched (vmap) in the training chunks
    # (train.run.seed_parallel): cheaper on XLA:CPU for the on-policy and MADDPG chunks (set on the CPU only; on a
    # GPU the batched seeds keep the device busy; docs/performance.md).
    seeds_in_sequence: bool = False


def make_env(scenario: str, agents: int | None = None):
    """``(env, auto-reset env, params)`` from :mod:`envs_jax`. ``highway`` is highway-v0 with ``agents``
    controlled vehicles (default 2), ``merge-cavs`` MARL_CAVs' merge with at most ``agents`` CAVs (3: easy traffic,
    the default; 4: medium), their observations flattened per agent (:mod:`envs_jax.traffic_autoreset`)."""
    import envs_jax

    if scenario in ("highway", "merge-cavs"):
        from envs_jax.traffic_autoreset import TrafficAutoResetWrapper

        if scenario == "highway":
            env = envs_jax.make("highway-v0", controlled_vehicles=2 if agents is None else int(agents))
        else:
            density = {3: 1, 4: 2}.get(3 if agents is None else int(agents))
            if density is None:
                raise ValueError(f"merge-cavs takes 3 agents (easy traffic) or 4 (medium), got {agents}")
            env = envs_jax.make("merge-cavs-v0", traffic_density=density)
        return env, TrafficAutoResetWrapper(env), env.default_params
    env = envs_jax.make(scenario)
    return env, envs_jax.AutoResetWrapper(env), env.default_params


def seed_keys(config: dict) -> jax.Array:
    """One raw PRNG key per seed: ``fold_in(PRNGKey(seed), i)``."""
    base = jax.random.PRNGKey(config["seed"])
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(config["num_seeds"]))


def make_train(config: dict, env=None) -> Trainer:
    """The trainer of ``config["algo"]``, its programs traced at ``config["matmul_precision"]`` (full float32
    matrix products by default on every backend). ``env``: optional ``(env, wrapped_env, params)``."""
    from train.config import COMMON, spec

    trainer = spec(config["algo"]).make_train(config, env)
    return with_matmul_precision(trainer, config.get("matmul_precision", COMMON["matmul_precision"]))


def with_matmul_precision(trainer: Trainer, precision: str) -> Trainer:
    """``trainer`` whose functions trace their matrix products at ``precision`` (``jax.default_matmul_precision``
    is read when an operation is traced, so the setting travels into every program built from them)."""

    def wrap(fn):
        if fn is None:
            return None

        @functools.wraps(fn)
        def traced_at_precision(*args, **kwargs):
            with jax.default_matmul_precision(precision):
                return fn(*args, **kwargs)

        return traced_at_precision

    return trainer._replace(init=wrap(trainer.init), run_chunk=wrap(trainer.run_chunk),
                            run_tail=wrap(trainer.run_tail), train=wrap(trainer.train),
                            evaluate=wrap(trainer.evaluate))


def make_train_fn(init: Callable, run_chunk: Callable, run_tail: Callable | None, n_full: int,
                  chunk_iters: int) -> Callable:
    """``train(key) -> (state, metrics)``: ``init`` then every chunk (and the tail), metrics over all iterations."""

    def train(key):
        rs = init(key)
        rs, m = jax.lax.scan(lambda s, c: run_chunk(s, c * chunk_iters), rs, jnp.arange(n_full))
        m = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), m)
        if run_tail is not None:
            rs, m2 = run_tail(rs, n_full * chunk_iters)
            m = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), m, m2)
        return rs, m

    return train


def episode_step_limit(env, params) -> int | None:
    """The time limit in policy steps, ``ceil(duration * policy_frequency)`` (the env truncates at it), or None
    when ``params`` is not concrete."""
    try:
        return int(math.ceil(float(params.duration) * env.policy_frequency - 1e-6))
    except (AttributeError, TypeError, jax.errors.ConcretizationTypeError):
        return None


def make_evaluate(wrapped, params, act: Callable, episodes: int, max_steps: int) -> Callable:
    """``evaluate(agent_state, key) -> records[episodes]``: the first finished episode of each of ``episodes``
    fresh envs, acting with ``act(agent_state, obs) -> action`` (greedy); ``records`` as
    :func:`jaxsmarl.metrics.episode_record` plus ``returned`` (False when ``max_steps`` ran out first).

    The scan stops at the env's time limit when that is shorter than ``max_steps`` (merge: 20 decisions, not
    200): every episode has ended by then and the steps use the first keys of ``split(k, max_steps)``, so the
    records are the same as with the full ``max_steps``, for a tenth of the work."""
    limit = episode_step_limit(wrapped, params)
    n_steps = max_steps if limit is None else min(int(max_steps), limit)

    def evaluate(agent_state, key):
        def episode(k):
            k_reset, k_run = jax.random.split(k)
            obs, st = wrapped.reset(k_reset, params)

            def body(c, kk):
                obs, st, rec, found = c
                a = act(agent_state, obs)
                obs, st, _, _, _, info = wrapped.step(kk, st, a, params)
                er = metrics.episode_record(info)
                take = er["returned"] & ~found
                rec = jax.tree.map(lambda new, old: jnp.where(take, new, old), er, rec)
                return (obs, st, rec, found | er["returned"]), None

            rec0 = {k: jnp.zeros((), bool if k == "returned" else jnp.float32)
                    for k in ("returned",) + metrics.EPISODE_FIELDS}
            (_, _, rec, _), _ = jax.lax.scan(body, (obs, st, rec0, jnp.zeros((), bool)),
                                             jax.random.split(k_run, max_steps)[:n_steps])
            return rec

        return jax.vmap(episode)(jax.random.split(key, max(1, episodes)))

    return evaluate


def make_offpolicy_train(config: dict, env, agent) -> Trainer:
    """The replay-based loop for ``agent``. ``env``: ``(env, wrapped_env, params)``."""
    env, wrapped, params = env
    E = config["num_envs"]
    U = config["updates_per_step"]
    B = config["batch_size"]
    warmup = config["warmup"]
    total_iters = config["total_steps"] // E
    chunk_iters = min(config["chunk_steps"] // E, total_iters)
    n_full, tail = divmod(total_iters, chunk_iters)
    capacity = min(config["buffer_size"], config["total_steps"])  # a never-filled buffer needs no more slots
    n_agents = env.num_agents

    def init(key) -> RunnerState:
        k_agent, k_env, k_run = jax.random.split(key, 3)
        obs, env_state = jax.vmap(wrapped.reset, in_axes=(0, None))(jax.random.split(k_env, E), params)
        return RunnerState(agent=agent.init(k_agent), buffer=buffers.init(agent.transition_example(), capacity),
                           env_state=env_state, obs=obs, key=k_run, iteration=jnp.int32(0))

    # A zero update-info record, for iterations before the warm-up ends.
    def _update_info_zeros():
        st = jax.eval_shape(agent.init, jax.random.PRNGKey(0))
        batch = jax.eval_shape(lambda: jax.tree.map(lambda x: jnp.zeros((B,) + x.shape, x.dtype),
                                                    agent.transition_example()))
        explore = jax.eval_shape(agent.exploration, jnp.int32(0))
        info = jax.eval_shape(agent.update, st, batch, jax.random.PRNGKey(0), explore)[1]
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), info)

    def iteration(rs: RunnerState, t):
        key, k_act, k_env, k_upd = jax.random.split(rs.key, 4)
        eps = agent.exploration(t * E)
        actions = agent.act(rs.agent, rs.obs, k_act, eps)
        obs, env_state, reward, cost, done, info = jax.vmap(wrapped.step, in_axes=(0, 0, 0, None))(
            jax.random.split(k_env, E), rs.env_state, actions, params)
        next_obs = jnp.where(done[:, None, None], info["terminal_obs"], obs)
        extra = {"active": info["alive"]} if "active" in agent.Transition.__dataclass_fields__ else {}
        tr = agent.Transition(obs=rs.obs, action=actions, reward=reward, cost=cost, next_obs=next_obs,
                              terminated=info["terminated"], truncated=info["truncated"], **extra)
        buf = buffers.add(rs.buffer, tr)

        def learn(agent_state):
            def one(a_state, k):
                k_sample, k_update = jax.random.split(k)
                return agent.update(a_state, buffers.sample(buf, k_sample, B), k_update, eps)

            agent_state, infos = jax.lax.scan(one, agent_state, jax.random.split(k_upd, U))
            return agent_state, jax.tree.map(lambda x: jnp.mean(x, axis=0), infos)

        def skip(agent_state):
            return agent_state, _update_info_zeros()

        agent_state, upd = jax.lax.cond((t + 1) * E >= warmup, learn, skip, rs.agent)
        out = {"episode": metrics.episode_record(info), "explore": eps, "update": upd,
               "updated": (t + 1) * E >= warmup}
        return RunnerState(agent=agent_state, buffer=buf, env_state=env_state, obs=obs, key=key,
                           iteration=rs.iteration + 1), out

    def make_chunk(length: int):
        def run(rs: RunnerState, start_iter):
            ts = jnp.asarray(start_iter, jnp.int32) + jnp.arange(length, dtype=jnp.int32)
            return jax.lax.scan(iteration, rs, ts)

        return run

    run_chunk = make_chunk(chunk_iters)
    run_tail = make_chunk(tail) if tail else None

    train = make_train_fn(init, run_chunk, run_tail, n_full, chunk_iters)

    evaluate = make_evaluate(wrapped, params, agent.greedy_act, config["eval_episodes"], config["eval_max_steps"])

    return Trainer(config=config, env=env, agent=agent, init=init, run_chunk=run_chunk, run_tail=run_tail,
                   train=train, evaluate=evaluate, total_iters=total_iters, chunk_iters=chunk_iters,
                   n_chunks=n_full + (1 if tail else 0))
