"""The compiled off-policy training loop (PureJaxRL style), shared by every replay-based algorithm.

``make_train(config)`` returns a :class:`Trainer` whose functions are pure and per seed; vmap them over seeds:

* ``init(key) -> RunnerState``: agent state, empty device-resident replay buffer, ``num_envs`` reset envs, RNG key.
* ``run_chunk(state, start_iter) -> (state, metrics)``: ``chunk_iters`` loop iterations in one ``lax.scan``.
  One iteration = act in every env (epsilon-greedy), step the auto-resetting envs, store the transitions
  (with the pre-reset observation as ``s'`` and per-agent ``terminated``), then ``updates_per_step`` gradient
  updates once ``warmup`` transitions are stored (Algorithm 1's inner loop). ``start_iter`` is unbatched
  (``in_axes=None``), so warm-up gating is a real branch, not a select, under ``vmap``.
* ``train(key) -> (state, metrics)``: ``init`` + every chunk, one pure function: ``jit(vmap(train))(keys)``.
* ``evaluate(agent_state, key) -> records``: ``eval_episodes`` greedy episodes (vmapped).

The host-side driver (:mod:`train.run`) calls ``init`` and ``run_chunk`` itself so it can log and checkpoint
between chunks; because it runs the very same compiled chunk, a resumed run is bit-identical.

An agent provides ``init(key)``, ``epsilon(env_step)``, ``act(state, obs, key, eps)``, ``greedy_act(state, obs)``,
``update(state, batch, key, eps) -> (state, info)``, ``transition_example()`` and ``Transition``.
"""

from __future__ import annotations

import math
from typing import Any, Callable, NamedTuple

import flax.struct
import jax
import jax.numpy as jnp

from jaxsmarl import buffers, metrics
from jaxsmarl.algos.csq import CSQAgent, CSQConfig

__all__ = ["RunnerState", "Trainer", "make_env", "make_agent", "make_train", "seed_keys"]


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


def make_env(scenario: str):
    """``(env, auto-reset env, params)`` from :mod:`envs_jax`."""
    import envs_jax

    env = envs_jax.make(scenario)
    return env, envs_jax.AutoResetWrapper(env), env.default_params


def make_agent(config: dict, env) -> CSQAgent:
    """The algorithm named by ``config["algo"]`` for ``env`` (csq and sq are the same algorithm)."""
    if config["algo"] in ("csq", "sq"):
        if not env.discrete:
            raise ValueError(f"scenario '{config['scenario']}' has continuous actions but '{config['algo']}' needs "
                             "discrete actions; use merge or roundabout")
        n = env.num_agents
        cfg = CSQConfig(
            num_actions=(int(env.num_actions),) * n, obs_dim=int(env.obs_shape[-1]),
            hidden_sizes=tuple(config["hidden_sizes"]), init=config["init"], lr=config["lr"],
            gamma=config["gamma"], tau=config["tau"], target_update_every=config["target_update_every"],
            batch_size=config["batch_size"], cost_threshold=tuple(config["cost_threshold"]),
            eps_start=tuple(config["eps_start"]), eps_min=tuple(config["eps_min"]), eps_decay=config["eps_decay"],
            leader_rule=config["leader_rule"], infeasible=config["infeasible"], tie_break=config["tie_break"],
            td_action_state=config["td_action_state"], td_action_noise=config["td_action_noise"],
            td_equilibrium_net=config["td_equilibrium_net"],
            bootstrap_on_truncation=config["bootstrap_on_truncation"],
        )
        return CSQAgent(cfg)
    raise ValueError(f"unknown algorithm '{config['algo']}'; choose csq or sq")


def seed_keys(config: dict) -> jax.Array:
    """One raw PRNG key per seed: ``fold_in(PRNGKey(seed), i)``."""
    base = jax.random.PRNGKey(config["seed"])
    return jax.vmap(lambda i: jax.random.fold_in(base, i))(jnp.arange(config["num_seeds"]))


def make_train(config: dict, env=None) -> Trainer:
    """Build the per-seed pure training functions. ``env``: optional ``(env, wrapped_env, params)``."""
    env, wrapped, params = make_env(config["scenario"]) if env is None else env
    agent = make_agent(config, env)
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
        info = jax.eval_shape(agent.update, st, batch, jax.random.PRNGKey(0), jnp.zeros(n_agents))[1]
        return jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), info)

    def iteration(rs: RunnerState, t):
        key, k_act, k_env, k_upd = jax.random.split(rs.key, 4)
        eps = agent.epsilon(t * E)
        actions = agent.act(rs.agent, rs.obs, k_act, eps)
        obs, env_state, reward, cost, done, info = jax.vmap(wrapped.step, in_axes=(0, 0, 0, None))(
            jax.random.split(k_env, E), rs.env_state, actions, params)
        next_obs = jnp.where(done[:, None, None], info["terminal_obs"], obs)
        tr = agent.Transition(obs=rs.obs, action=actions, reward=reward, cost=cost, next_obs=next_obs,
                              terminated=info["terminated"], truncated=info["truncated"])
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
        out = {"episode": metrics.episode_record(info), "eps": eps, "update": upd}
        return RunnerState(agent=agent_state, buffer=buf, env_state=env_state, obs=obs, key=key,
                           iteration=rs.iteration + 1), out

    def make_chunk(length: int):
        def run(rs: RunnerState, start_iter):
            ts = jnp.asarray(start_iter, jnp.int32) + jnp.arange(length, dtype=jnp.int32)
            return jax.lax.scan(iteration, rs, ts)

        return run

    run_chunk = make_chunk(chunk_iters)
    run_tail = make_chunk(tail) if tail else None

    def train(key):
        rs = init(key)
        rs, m = jax.lax.scan(lambda s, c: run_chunk(s, c * chunk_iters), rs, jnp.arange(n_full))
        m = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), m)
        if run_tail is not None:
            rs, m2 = run_tail(rs, n_full * chunk_iters)
            m = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), m, m2)
        return rs, m

    def evaluate(agent_state, key):
        """Greedy (eps = 0) episodes; the first finished episode of each of ``eval_episodes`` fresh envs."""

        def episode(k):
            k_reset, k_run = jax.random.split(k)
            obs, st = wrapped.reset(k_reset, params)

            def body(c, kk):
                obs, st, rec, found = c
                a = agent.greedy_act(agent_state, obs)
                obs, st, _, _, _, info = wrapped.step(kk, st, a, params)
                er = metrics.episode_record(info)
                take = er["returned"] & ~found
                rec = jax.tree.map(lambda new, old: jnp.where(take, new, old), er, rec)
                return (obs, st, rec, found | er["returned"]), None

            rec0 = {k: jnp.zeros((), bool if k == "returned" else jnp.float32)
                    for k in ("returned",) + metrics.EPISODE_FIELDS}
            (_, _, rec, _), _ = jax.lax.scan(body, (obs, st, rec0, jnp.zeros((), bool)),
                                             jax.random.split(k_run, config["eval_max_steps"]))
            return rec

        return jax.vmap(episode)(jax.random.split(key, max(1, config["eval_episodes"])))

    return Trainer(config=config, env=env, agent=agent, init=init, run_chunk=run_chunk, run_tail=run_tail,
                   train=train, evaluate=evaluate, total_iters=total_iters, chunk_iters=chunk_iters,
                   n_chunks=n_full + (1 if tail else 0))
