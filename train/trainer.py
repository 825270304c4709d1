"""The trainer contract every training loop fulfils, and the parts the loops share (PureJaxRL style).

``train.build.make_train(config)`` returns a :class:`Trainer` for ``config["algo"]`` (the algorithm's agent in its
loop). Its functions are pure and per seed; vmap them over seeds:

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

The loops: :mod:`train.offpolicy` (replay-based: CSQ, the MADDPG family) and :mod:`train.onpolicy` (MAPPO-L, MACPO).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from envs_jax.time_limit import episode_step_limit
from jaxsmarl import metrics

__all__ = ["Trainer", "make_env", "config_env", "make_evaluate", "make_train_fn", "seed_keys",
           "episode_step_limit", "with_matmul_precision", "chunk_layout", "assemble_trainer"]


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
    # (train.parallel.seed_parallel): cheaper on XLA:CPU for the on-policy and MADDPG chunks (set on the CPU only; on a
    # GPU the batched seeds keep the device busy; docs/performance.md).
    seeds_in_sequence: bool = False


# highway-env's merge-v0 has no time limit; training and evaluation need one. Agents drive at 20 m/s or more and
# leave the task at x = 370 m (at most 17 s from the farthest start), so the limit only cuts stalled episodes.
MERGE_V0_DURATION = 30.0
# The authors' scenarios with K >= 3 agents: their versions on the traffic core (K = 2 keeps the two-agent env).
AUTHORS_K_TASKS = {"merge": "merge-k", "roundabout": "roundabout-k", "intersection": "intersection-k",
                   "racetrack": "racetrack-k"}


def make_env(scenario: str, agents: int | None = None, env_params: dict | None = None):
    """``(env, auto-reset env, params)`` from :mod:`envs_jax`. ``highway`` is highway-v0 with ``agents``
    controlled vehicles (default 2), ``merge-v0`` likewise highway-env's merge-v0 (with a time limit of
    ``MERGE_V0_DURATION`` seconds), ``merge-cavs`` MARL_CAVs' merge with at most ``agents`` CAVs (3: easy traffic,
    the default; 4: medium), ``racetrack-v0`` highway-env's racetrack with ``agents`` controlled vehicles (default
    3), their observations flattened per agent (:mod:`envs_jax.traffic_autoreset`); the authors' four scenarios
    with ``agents`` >= 3 their versions with K agents (``merge-k``, ``roundabout-k``, ``intersection-k``,
    ``racetrack-k``, same wrapper).
    ``env_params``: values replacing fields of the default params (a configuration's ``env``,
    :mod:`train.env_params`)."""
    import envs_jax
    from envs_jax.traffic_autoreset import TrafficAutoResetWrapper
    from train.env_params import with_values

    k = None if agents is None else int(agents)
    if scenario in AUTHORS_K_TASKS and k is not None and k > 2:
        env = envs_jax.make(AUTHORS_K_TASKS[scenario], controlled_vehicles=k)
    elif scenario == "highway":
        env = envs_jax.make("highway-v0", controlled_vehicles=2 if k is None else k)
    elif scenario == "merge-v0":
        env = envs_jax.make("merge-v0", controlled_vehicles=2 if k is None else k, duration=MERGE_V0_DURATION)
    elif scenario == "racetrack-v0":
        env = envs_jax.make("racetrack-v0", controlled_vehicles=3 if k is None else k)
    elif scenario == "merge-cavs":
        density = {3: 1, 4: 2}.get(3 if k is None else k)
        if density is None:
            raise ValueError(f"merge-cavs takes 3 agents (easy traffic) or 4 (medium), got {agents}")
        env = envs_jax.make("merge-cavs-v0", traffic_density=density)
    else:  # the authors' two-agent scenarios
        env = envs_jax.make(scenario)
        return env, envs_jax.AutoResetWrapper(env), with_values(scenario, env.default_params, env_params or {})
    wrapped = TrafficAutoResetWrapper(env)
    return env, wrapped, with_values(scenario, env.default_params, env_params or {})


def config_env(config: dict):
    """:func:`make_env` for run configuration ``config`` (its scenario, agents and environment parameters)."""
    return make_env(config["scenario"], config.get("agents"), config.get("env"))


def seed_keys(config: dict) -> jax.Array:
    """One raw PRNG key per seed: ``fold_in(PRNGKey(seed), i)``."""
    base = jax.random.PRNGKey(config["seed"])
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(config["num_seeds"]))


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

            shapes = jax.eval_shape(lambda: metrics.episode_record(
                wrapped.step(k_run, st, act(agent_state, obs), params)[5]))
            rec0 = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), shapes)
            (_, _, rec, _), _ = jax.lax.scan(body, (obs, st, rec0, jnp.zeros((), bool)),
                                             jax.random.split(k_run, max_steps)[:n_steps])
            return rec

        return jax.vmap(episode)(jax.random.split(key, max(1, episodes)))

    return evaluate


def chunk_layout(config: dict) -> tuple[int, int, int, int]:
    """``(total_iters, chunk_iters, n_full, tail)``: loop iterations of the run and of one chunk (each iteration
    steps all ``num_envs`` envs once), the number of full chunks and the iterations of the shorter last one."""
    total_iters = config["total_steps"] // config["num_envs"]
    chunk_iters = min(config["chunk_steps"] // config["num_envs"], total_iters)
    n_full, tail = divmod(total_iters, chunk_iters)
    return total_iters, chunk_iters, n_full, tail


def assemble_trainer(config: dict, env, wrapped, params, agent, init: Callable, make_chunk: Callable,
                     **extra) -> Trainer:
    """The :class:`Trainer` of a loop given by ``init(key)`` and ``make_chunk(length) -> run_chunk``: the full and
    the tail chunk, ``train`` over all of them, and the greedy evaluation of ``agent.greedy_act``. ``extra``:
    further :class:`Trainer` fields (``seeds_in_sequence``)."""
    total_iters, chunk_iters, n_full, tail = chunk_layout(config)
    run_chunk = make_chunk(chunk_iters)
    run_tail = make_chunk(tail) if tail else None
    train = make_train_fn(init, run_chunk, run_tail, n_full, chunk_iters)
    evaluate = make_evaluate(wrapped, params, agent.greedy_act, config["eval_episodes"], config["eval_max_steps"])
    return Trainer(config=config, env=env, agent=agent, init=init, run_chunk=run_chunk, run_tail=run_tail,
                   train=train, evaluate=evaluate, total_iters=total_iters, chunk_iters=chunk_iters,
                   n_chunks=n_full + (1 if tail else 0), **extra)

