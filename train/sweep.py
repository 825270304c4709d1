"""Sweeps in one program: ``--sweep KEY=[v1,v2,...]`` (repeatable) trains every combination of the values, each
with the run's seeds, in one compiled program.

Only real-valued keys can be swept (learning rates, discounts, cost thresholds, multiplier rates, exploration
schedules, loss weights): their values enter the program as arrays, so the program's shapes and structure are the
same for every configuration. Integer, list, choice and true/false keys fix shapes (batch, buffer, network widths,
budgets) or the program's structure, and are refused with a ValueError naming them and the sweepable keys.

The sweep program maps over the configurations one after another on each device and, inside, runs the seeds
exactly as a one-configuration run does (batched, or one after another, over the same seed sharding). So seed
``i`` of configuration ``c`` is computed by the same per-device program as seed ``i`` of a separate run with
configuration ``c``; only that configuration's values arrive as inputs instead of constants.
"""

from __future__ import annotations

import itertools
import json
from typing import Any, Callable

from train.config import COMMON_RULES, Num, PerAgent, spec, validate

__all__ = ["parse_sweep", "sweepable_keys", "sweep_configs", "config_name", "trainer_for", "sweep_parallel",
           "check_traceable"]


def sweepable_keys(algo: str) -> list[str]:
    """The keys of ``algo`` a sweep may vary: the real-valued ones (a number, or one per agent)."""
    rules = {**COMMON_RULES, **spec(algo).rules}
    return [k for k, r in rules.items() if isinstance(r, (Num, PerAgent))]


def parse_sweep(items: list[str]) -> dict[str, list]:
    """``["lr=[1e-3,3e-4]", ...]`` -> ``{"lr": [0.001, 0.0003]}`` (JSON lists; ValueError for anything else)."""
    out: dict[str, list] = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"--sweep expects KEY=[v1,v2,...], got {item!r}")
        k, v = (s.strip() for s in item.split("=", 1))
        try:
            values = json.loads(v)
        except json.JSONDecodeError:
            raise ValueError(f"--sweep {k}: the values must be a JSON list such as [1e-3,3e-4], got {v!r}") from None
        if not isinstance(values, list) or len(values) < 2:
            raise ValueError(f"--sweep {k}: give a JSON list of at least two values, got {v!r}")
        if k in out:
            raise ValueError(f"--sweep {k} is given twice; list all its values in one --sweep")
        out[k] = values
    return out


def sweep_configs(config: dict, sweep: dict[str, list]) -> list[dict]:
    """Every combination of the swept values applied to ``config`` (validated; the first key varies slowest).
    Refuses keys that are not sweepable, naming them and the allowed keys."""
    allowed = sweepable_keys(config["algo"])
    bad = [k for k in sweep if k not in allowed]
    if bad:
        raise ValueError(f"cannot sweep {', '.join(repr(k) for k in bad)}: a sweep runs every configuration in one "
                         f"program, so it may only vary real-valued keys (integer, list, choice and true/false keys "
                         f"fix the program's shapes or structure; train those as separate runs). Sweepable keys of "
                         f"{config['algo']}: {', '.join(allowed)}")
    keys = list(sweep)
    return [validate({**config, **dict(zip(keys, combo))}) for combo in itertools.product(*sweep.values())]


def config_name(config: dict, keys: list[str]) -> str:
    """A folder name for one configuration of a sweep: ``lr=0.001,cost_threshold=2_3``."""
    def text(v):
        return "_".join(f"{x:g}" for x in v) if isinstance(v, list) else f"{v:g}"

    return ",".join(f"{k}={text(config[k])}" for k in keys)


def sweep_values(configs: list[dict], keys: list[str]):
    """``{key: float32 array [C] or [C, n_agents]}``: the swept values of every configuration."""
    import numpy as np

    return {k: np.asarray([c[k] for c in configs], np.float32) for k in keys}


def trainer_for(config: dict, env, values: dict):
    """The trainer of ``config`` with ``values`` (traced arrays of one configuration) in place of the swept keys."""
    from train.build import make_train

    cfg = dict(config)
    for k, v in values.items():
        cfg[k] = [v[i] for i in range(v.shape[0])] if v.ndim else v
    return make_train(cfg, env)


def check_traceable(config: dict, env, keys: list[str]) -> None:
    """Trace the training programs with ``keys`` as inputs; a key the program reads as a Python number (to set a
    shape or a loop) cannot be swept and is refused here, before anything is compiled."""
    import jax
    import jax.numpy as jnp

    from train.build import make_train

    trainer = make_train(config, env)
    values = {k: jax.ShapeDtypeStruct(jnp.shape(jnp.asarray(config[k], jnp.float32)), jnp.float32) for k in keys}
    key = jax.ShapeDtypeStruct((2,), jnp.uint32)

    def probe(vals, k):
        t = trainer_for(config, env, vals)
        state = t.init(k)
        state, _ = t.run_chunk(state, jnp.int32(0))
        return t.evaluate(state.agent, k)

    try:
        jax.eval_shape(probe, values, key)
    except (jax.errors.ConcretizationTypeError, jax.errors.TracerBoolConversionError,
            jax.errors.TracerIntegerConversionError, TypeError) as e:
        raise ValueError(f"cannot sweep {', '.join(keys)} with {config['algo']}: the program uses the value of one "
                         f"of them to build itself ({type(e).__name__}); train those values as separate runs") from e
    del trainer


def sweep_parallel(fn: Callable, num_seeds: int, in_axes=0, donate_argnums=(), sequential: bool = False):
    """``fn(values, *args)`` (per seed; ``values``: one configuration's swept values) over ``[C, S]``-leading
    arguments: the configurations one after another (``lax.map``), inside each the seeds as in
    :func:`train.parallel.seed_parallel` (batched or in sequence, the seed axis split over the devices).
    ``in_axes`` is for ``args``: 0 (a ``[C, S]`` leading pair) or None (shared). Returns a jitted
    ``f(values [C, ...], *args)``."""
    import jax
    from jax.sharding import PartitionSpec

    from train.parallel import seed_loop, seed_sharding

    axes = tuple(in_axes) if isinstance(in_axes, (tuple, list)) else (in_axes,)

    def all_configs(values, *args):
        mapped = tuple(a for a, ax in zip(args, axes) if ax == 0)

        def one(xs):
            vals, ms = xs
            it = iter(ms)
            full = tuple(next(it) if ax == 0 else a for a, ax in zip(args, axes))

            def per_seed(*a):
                return fn(vals, *a)

            vfn = seed_loop(per_seed, axes) if sequential else jax.vmap(per_seed, in_axes=axes)
            return vfn(*full)

        return jax.lax.map(one, (values, mapped))

    sharding = seed_sharding(num_seeds)
    donate = tuple(i + 1 for i in donate_argnums)
    if sharding is None:
        return jax.jit(all_configs, donate_argnums=donate)
    cs, rep = PartitionSpec(None, "seeds"), PartitionSpec()
    specs = (rep,) + tuple(rep if a is None else cs for a in axes)
    return jax.jit(jax.shard_map(all_configs, mesh=sharding.mesh, in_specs=specs, out_specs=cs, check_vma=False),
                   donate_argnums=donate)


def placement(num_seeds: int) -> Any:
    """The sharding of ``[C, S, ...]`` arrays: the seed axis split as in a one-configuration run."""
    from jax.sharding import NamedSharding, PartitionSpec

    from train.parallel import seed_sharding

    s = seed_sharding(num_seeds)
    return None if s is None else NamedSharding(s.mesh, PartitionSpec(None, "seeds"))


def run_sweep(config: dict, sweep: dict[str, list], out: str, *, overwrite: bool = False, env=None,
              verbose: bool = True) -> dict:
    """Train every configuration of ``sweep`` over ``config`` (each with ``config["num_seeds"]`` seeds) in one
    compiled program into run folder ``out``::

        sweep.json                     the swept keys, every configuration's values, folder and summary
        configs/<key=value,...>/       per configuration, as a run folder: config.json, episodes.csv,
                                       learner.csv, summary.json, eval.csv
        figures/curves.png|pdf, figures/learner.png   the configurations' learning curves side by side
        checkpoints/<env steps>/       the training state of every configuration and seed ([C, S, ...])

    Returns ``{"state": [C, S] state, "configs": [config], "summaries": [summary]}``."""
    import os
    import time

    import jax
    import jax.numpy as jnp

    from jaxsmarl import metrics
    from jaxsmarl.checkpoints import Checkpointer
    from jaxsmarl.learner_log import LearnerLog, chunk_rows
    from train import distributed
    from train.build import make_train
    from train.evaluation import eval_rows, write_eval_csv
    from train.lock import RunLock
    from train.run_folder import check_out_dir, clear_run_dir
    from train.trainer import make_env, seed_keys

    configs = sweep_configs(config, sweep)
    keys = list(sweep)
    names = [config_name(c, keys) for c in configs]
    out = os.path.abspath(out)
    main = distributed.is_main()
    multi = distributed.process_count() > 1
    verbose = verbose and main
    lock = RunLock(out).acquire() if main and os.path.isdir(out) else None
    try:
        check_out_dir(out, False, overwrite)
        distributed.sync("sweep folder checked")
        if main:
            os.makedirs(out, exist_ok=True)
            lock = lock or RunLock(out).acquire()
            if overwrite:
                clear_run_dir(out)
        distributed.sync("sweep folder ready")

        env = make_env(config["scenario"]) if env is None else env
        check_traceable(config, env, keys)
        trainer = make_train(config, env)
        S, C, E = config["num_seeds"], len(configs), config["num_envs"]
        values = sweep_values(configs, keys)

        def built(name):
            return lambda v, *a: getattr(trainer_for(config, env, v), name)(*a)

        seq = trainer.seeds_in_sequence
        init_fn = sweep_parallel(built("init"), S)
        chunk_fn = sweep_parallel(built("run_chunk"), S, in_axes=(0, None), donate_argnums=(0,), sequential=seq)
        tail_fn = (sweep_parallel(built("run_tail"), S, in_axes=(0, None), donate_argnums=(0,), sequential=seq)
                   if trainer.run_tail is not None else None)
        eval_fn = sweep_parallel(built("evaluate"), S, in_axes=(0, 0))
        place = placement(S)

        def put(x):
            return distributed.to_global(x, place) if multi else x

        t0 = time.perf_counter()
        seed_k = jnp.broadcast_to(seed_keys(config), (C,) + seed_keys(config).shape)  # every configuration: same seeds
        state = init_fn(values, put(seed_k))
        t_compile = time.perf_counter()
        chunk_c = chunk_fn.lower(values, state, jnp.int32(0)).compile()
        tail_c = tail_fn.lower(values, state, jnp.int32(0)).compile() if tail_fn is not None else None
        compile_s = time.perf_counter() - t_compile
        logs = [metrics.EpisodeLog(S) for _ in configs]
        learners = [LearnerLog() for _ in configs]
        ckpt = Checkpointer(os.path.join(out, "checkpoints"), max_to_keep=2)
        every = (config["checkpoint_every"] // config["chunk_steps"]) if config["checkpoint_every"] else 0
        train_s, steps_run = 0.0, 0
        name = f"{config['scenario']}/{config['algo']} sweep {C}x{S}"
        for c in range(trainer.n_chunks):
            start = c * trainer.chunk_iters
            fn = tail_c if (tail_c is not None and c == trainer.n_chunks - 1) else chunk_c
            t = time.perf_counter()
            state, m = fn(values, state, jnp.int32(start))
            m = distributed.to_host(m)
            train_s += time.perf_counter() - t
            n_iter = m["episode"]["returned"].shape[2]
            steps_run += n_iter * E
            env_steps = (start + n_iter) * E
            for i in range(C):
                mi = jax.tree.map(lambda x: x[i], m)
                logs[i].add_steps(mi["episode"], start, E)
                if "update" in mi:
                    learners[i].add(chunk_rows(mi["update"], env_steps, mi.get("updated")))
            if c == trainer.n_chunks - 1 or (every and (c + 1) % every == 0):
                ckpt.save(env_steps, state, {"chunks_done": c + 1, "env_steps": env_steps, "sweep": sweep,
                                             "num_processes": distributed.process_count()})
            if verbose:
                print(f"{name}: {env_steps}/{trainer.total_iters * E} env steps per seed "
                      f"({C * S * steps_run / max(train_s, 1e-9):,.0f} steps/s over all)", flush=True)
        ckpt.close()

        ev = None
        if config["eval_episodes"] > 0:
            ek = jax.random.split(jax.random.PRNGKey(config["seed"] + 10_000), S)  # as train.evaluation.evaluate_state
            ev = distributed.to_host(eval_fn(values, state.agent, put(jnp.broadcast_to(ek, (C,) + ek.shape))))
        timing = {"setup_s": time.perf_counter() - t0 - train_s, "compile_s": compile_s, "train_s": train_s,
                  "env_steps_run": steps_run, "configurations": C,
                  "env_steps_per_s_all": C * S * steps_run / max(train_s, 1e-9)}
        summaries = []
        for i, (cfg, folder) in enumerate(zip(configs, names)):
            s = {"config": cfg, "summary": metrics.summarize(logs[i]), "finished": True, "timing": timing,
                 "sweep": {k: cfg[k] for k in keys}}
            if learners[i].rows:
                s["learner"] = learners[i].summary()
            rows = None
            if ev is not None:
                rows, s["eval"] = eval_rows(jax.tree.map(lambda x: x[i], ev), cfg)
            summaries.append(s)
            if main:
                d = os.path.join(out, "configs", folder)
                os.makedirs(d, exist_ok=True)
                metrics.write_json(os.path.join(d, "config.json"), cfg)
                logs[i].write_csv(os.path.join(d, "episodes.csv"))
                learners[i].write_csv(os.path.join(d, "learner.csv"))
                metrics.write_json(os.path.join(d, "summary.json"), s)
                if rows:
                    write_eval_csv(os.path.join(d, "eval.csv"), rows)
        if main:
            metrics.write_json(os.path.join(out, "sweep.json"), {
                "base": config, "sweep": sweep, "timing": timing,
                "configurations": [{"folder": os.path.join("configs", n), "values": s["sweep"],
                                    "last": {k: v["last"] for k, v in s["summary"].items()
                                             if isinstance(v, dict) and "last" in v}}
                                   for n, s in zip(names, summaries)]})
            _sweep_figures(out, names, config)
        distributed.sync("sweep finished")
        return {"state": state, "configs": configs, "summaries": summaries, "names": names}
    finally:
        if lock is not None:
            lock.release()


def _sweep_figures(out: str, names: list[str], config: dict) -> list[str]:
    """The configurations' learning curves (and multipliers / cost estimates) side by side in ``out/figures``."""
    import os

    from train.figures import load_run, plot_learner, plot_scenario

    runs = {n: load_run(os.path.join(out, "configs", n)) for n in names}
    runs = {n: r for n, r in runs.items() if r is not None}
    os.makedirs(os.path.join(out, "figures"), exist_ok=True)
    paths = plot_scenario(config["scenario"], runs, os.path.join(out, "figures", "curves"))
    return paths + plot_learner(runs, os.path.join(out, "figures", "learner"),
                                title=f"{config['scenario']} {config['algo']} sweep")
