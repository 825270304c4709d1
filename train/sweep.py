"""Sweeps in one program: ``--sweep KEY=[v1,v2,...]`` (repeatable) trains every combination of the values, each
with the run's seeds, in one compiled program.

Only real-valued keys can be swept (learning rates, discounts, cost thresholds, multiplier rates, exploration
schedules, loss weights) and the real-valued environment parameters, named ``env.<field>`` (reward weights, costs,
speed ranges; :mod:`train.env_params`): their values enter the program as arrays, so the program's shapes and
structure are the same for every configuration. Integer, list, choice and true/false keys fix shapes (batch, buffer,
network widths, budgets) or the program's structure, and are refused with a ValueError naming them and the
sweepable keys.

The sweep program maps over the configurations one after another on each device and, inside, runs the seeds
exactly as a one-configuration run does (batched, or one after another, over the same seed sharding). So seed
``i`` of configuration ``c`` is computed by the same per-device program as seed ``i`` of a separate run with
configuration ``c``; only that configuration's values arrive as inputs instead of constants.

A sweep's folder is resumed like a run's (``--resume``): the same sweep only (:mod:`train.sweep_folder`), from
its newest intact checkpoint of the ``[C, S]`` state, bit-identical to an uninterrupted sweep.
"""

from __future__ import annotations

import itertools
import json
from typing import Any, Callable

from train.config import COMMON_RULES, ENV_PREFIX, Num, PerAgent, spec, validate, with_overrides
from train.env_params import real_fields

__all__ = ["parse_sweep", "sweepable_keys", "sweep_configs", "config_name", "trainer_for", "sweep_parallel",
           "check_traceable", "swept_value", "run_sweep"]


def sweepable_keys(algo: str, params=None) -> list[str]:
    """The keys of ``algo`` a sweep may vary: the real-valued ones (a number, or one per agent), and with the
    scenario's ``params`` the real-valued environment parameters (``env.<field>``)."""
    rules = {**COMMON_RULES, **spec(algo).rules}
    keys = [k for k, r in rules.items() if isinstance(r, (Num, PerAgent))]
    return keys + ([ENV_PREFIX + f for f in real_fields(params)] if params is not None else [])


def swept_value(config: dict, key: str):
    """The value of swept ``key`` in ``config`` (``env.<field>``: that field of ``config["env"]``)."""
    return config["env"][key[len(ENV_PREFIX):]] if key.startswith(ENV_PREFIX) else config[key]


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


def sweep_configs(config: dict, sweep: dict[str, list], params=None) -> list[dict]:
    """Every combination of the swept values applied to ``config`` (validated; the first key varies slowest).
    Refuses keys that are not sweepable, naming them and the allowed keys. ``params``: the scenario's environment
    parameters, needed to check ``env.<field>`` keys (built from ``config`` when None)."""
    if params is None and any(k.startswith(ENV_PREFIX) for k in sweep):
        from train.trainer import config_env

        params = config_env(config)[2]
    allowed = sweepable_keys(config["algo"], params)
    bad = [k for k in sweep if k not in allowed]
    if bad:
        env_keys = [k for k in allowed if k.startswith(ENV_PREFIX)]
        own = [k for k in allowed if not k.startswith(ENV_PREFIX)]
        env_text = (f"; environment parameters of {config['scenario']}: {', '.join(env_keys)}" if env_keys else
                    f"; and the real-valued environment parameters of {config['scenario']} as env.<field>")
        raise ValueError(f"cannot sweep {', '.join(repr(k) for k in bad)}: a sweep runs every configuration in one "
                         f"program, so it may only vary real-valued keys (integer, list, choice and true/false keys "
                         f"fix the program's shapes or structure, as do environment parameters that are not "
                         f"real numbers or arrays of them; train those as separate runs). Sweepable keys of "
                         f"{config['algo']}: {', '.join(own)}{env_text}")
    keys = list(sweep)
    configs = [validate(with_overrides(config, dict(zip(keys, combo)))) for combo in itertools.product(*sweep.values())]
    if params is not None:
        from train.env_params import with_values

        for c in configs:  # shapes and ranges of the environment values
            with_values(config["scenario"], params, {k[len(ENV_PREFIX):]: c["env"][k[len(ENV_PREFIX):]]
                                                     for k in keys if k.startswith(ENV_PREFIX)})
    return configs


def config_name(config: dict, keys: list[str]) -> str:
    """A folder name for one configuration of a sweep: ``lr=0.001,cost_threshold=2_3``."""
    def text(v):
        return "_".join(text(x) for x in v) if isinstance(v, list) else f"{v:g}"

    return ",".join(f"{k}={text(swept_value(config, k))}" for k in keys)


def sweep_values(configs: list[dict], keys: list[str]):
    """``{key: float32 array [C, ...]}``: the swept values of every configuration (``[C]``, ``[C, n_agents]`` or
    ``[C, *shape]`` of an environment parameter)."""
    import numpy as np

    return {k: np.asarray([swept_value(c, k) for c in configs], np.float32) for k in keys}


def trainer_for(config: dict, env, values: dict):
    """The trainer of ``config`` with ``values`` (traced arrays of one configuration) in place of the swept keys;
    ``env``: ``(env, wrapped_env, params)``, whose params take the swept environment values."""
    from train.build import make_train

    cfg, fields = dict(config), {}
    base, wrapped, params = env
    for k, v in values.items():
        if k.startswith(ENV_PREFIX):
            default = getattr(params, k[len(ENV_PREFIX):])
            fields[k[len(ENV_PREFIX):]] = tuple(v[i] for i in range(v.shape[0])) if isinstance(default, tuple) else v
        else:
            cfg[k] = [v[i] for i in range(v.shape[0])] if v.ndim else v
    return make_train(cfg, (base, wrapped, params.replace(**fields)) if fields else env)


def check_traceable(config: dict, env, keys: list[str]) -> None:
    """Trace the training programs with ``keys`` as inputs; a key the program reads as a Python number (to set a
    shape or a loop) cannot be swept and is refused here, before anything is compiled."""
    import jax
    import jax.numpy as jnp

    from train.build import make_train

    trainer = make_train(config, env)
    values = {k: jax.ShapeDtypeStruct(jnp.shape(jnp.asarray(swept_value(config, k) if not k.startswith(ENV_PREFIX)
                                                            else getattr(env[2], k[len(ENV_PREFIX):]), jnp.float32)),
                                      jnp.float32) for k in keys}
    key = jax.ShapeDtypeStruct((2,), jnp.uint32)

    def probe(vals, k):
        t = trainer_for(config, env, vals)
        state = t.init(k)
        state, _ = t.run_chunk(state, jnp.int32(0))
        return t.evaluate(state.agent, k)

    try:
        jax.eval_shape(probe, values, key)
    except (jax.errors.ConcretizationTypeError, jax.errors.TracerBoolConversionError,
            jax.errors.TracerIntegerConversionError, jax.errors.TracerArrayConversionError, TypeError) as e:
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


def run_sweep(config: dict, sweep: dict[str, list], out: str, *, resume: bool = False, overwrite: bool = False,
              env=None, verbose: bool = True, max_chunks: int | None = None) -> dict:
    """Train every configuration of ``sweep`` over ``config`` (each with ``config["num_seeds"]`` seeds) in one
    compiled program into run folder ``out``::

        sweep.json                     the swept keys, every configuration's values, folder and summary
                                       (train.sweep_folder)
        configs/<key=value,...>/       per configuration, as a run folder: config.json, episodes.csv,
                                       learner.csv, summary.json, eval.csv
        figures/curves.png|pdf, figures/learner.png   the configurations' learning curves side by side
        checkpoints/<env steps>/       the training state of every configuration and seed ([C, S, ...])

    ``resume``: continue the same sweep in ``out`` from its newest intact checkpoint, bit-identical to an
    uninterrupted sweep (another sweep or configuration is refused). ``max_chunks`` stops early (for tests: an
    interruption). Returns ``{"state": [C, S] state, "configs": [config], "summaries": [summary], "names"}``."""
    import os
    import time

    import jax
    import jax.numpy as jnp

    from jaxsmarl import metrics
    from jaxsmarl.checkpoints import Checkpointer, CheckpointError
    from jaxsmarl.learner_log import LearnerLog, chunk_rows
    from train import distributed
    from train.build import make_train
    from train.console import say
    from train.evaluation import eval_rows, write_eval_csv
    from train.lock import RunLock
    from train.run_folder import check_out_dir, check_process_count, clear_run_dir, set_aside
    from train.sweep_folder import SWEEP_FILE, check_same_sweep, read_sweep
    from train.trainer import config_env, seed_keys

    env = config_env(config) if env is None else env
    configs = sweep_configs(config, sweep, env[2])
    keys = list(sweep)
    names = [config_name(c, keys) for c in configs]
    swept = [{k: swept_value(c, k) for k in keys} for c in configs]
    out = os.path.abspath(out)
    main = distributed.is_main()
    multi = distributed.process_count() > 1
    verbose = verbose and main
    lock = RunLock(out).acquire() if main and os.path.isdir(out) else None
    try:
        check_out_dir(out, resume, overwrite)
        if resume:
            check_same_sweep(read_sweep(out), configs, keys, swept, out)
        distributed.sync("sweep folder checked")
        folders = [os.path.join(out, "configs", n) for n in names]
        if main:
            os.makedirs(out, exist_ok=True)
            lock = lock or RunLock(out).acquire()
            if overwrite and not resume:
                clear_run_dir(out)
            if not resume:  # the record a resume is checked against, written before anything is trained
                metrics.write_json(os.path.join(out, SWEEP_FILE), {
                    "base": config, "sweep": sweep, "finished": False,
                    "configurations": [{"folder": os.path.join("configs", n), "values": v}
                                       for n, v in zip(names, swept)]})
            for cfg, d in zip(configs, folders):
                os.makedirs(d, exist_ok=True)
                metrics.write_json(os.path.join(d, "config.json"), cfg)
        distributed.sync("sweep folder ready")

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

        name = f"{config['scenario']}/{config['algo']} sweep {C}x{S}"
        t0 = time.perf_counter()
        seed_k = jnp.broadcast_to(seed_keys(config), (C,) + seed_keys(config).shape)  # every configuration: same seeds
        state = init_fn(values, put(seed_k))
        logs = [metrics.EpisodeLog(S) for _ in configs]
        learners = [LearnerLog() for _ in configs]
        ckpt = Checkpointer(os.path.join(out, "checkpoints"), max_to_keep=2)
        done_chunks, prev_train_s = 0, 0.0
        if resume:
            skipped: list[CheckpointError] = []
            try:
                check_process_count(ckpt)
                _, state, meta = ckpt.restore_valid(state, skipped.append)
                check_process_count(ckpt, meta)
            except ValueError:
                ckpt.close()
                raise
            for e in skipped:
                if main:
                    say(f"{name}: skipped checkpoint {e.step} ({e.reason}); moved it to {set_aside(out, e.step)}",
                        False)
            distributed.sync("damaged checkpoints set aside")
            done_chunks, prev_train_s = int(meta["chunks_done"]), float(meta.get("train_s_total", 0.0))
            for i, d in enumerate(folders):  # episodes logged after the checkpoint are replayed
                if os.path.exists(os.path.join(d, "episodes.csv")):
                    logs[i] = metrics.EpisodeLog.read_csv(os.path.join(d, "episodes.csv"), S)
                logs[i].truncate(int(meta["env_steps"]))
                learners[i] = LearnerLog.read_csv(os.path.join(d, "learner.csv"))
                learners[i].truncate(int(meta["env_steps"]))
            state = distributed.to_global(state, place) if multi else jax.device_put(state, place)
            if verbose:
                say(f"{name}: resumed from {out}/checkpoints at {meta['env_steps']} env steps", False)
        t_compile = time.perf_counter()
        chunk_c = tail_c = None
        if done_chunks < trainer.n_chunks:
            chunk_c = chunk_fn.lower(values, state, jnp.int32(0)).compile()
            tail_c = tail_fn.lower(values, state, jnp.int32(0)).compile() if tail_fn is not None else None
        compile_s = time.perf_counter() - t_compile
        every = (config["checkpoint_every"] // config["chunk_steps"]) if config["checkpoint_every"] else 0
        train_s, steps_run, n_run = 0.0, 0, 0
        for c in range(done_chunks, trainer.n_chunks):
            if max_chunks is not None and n_run >= max_chunks:
                break
            start = c * trainer.chunk_iters
            fn = tail_c if (tail_c is not None and c == trainer.n_chunks - 1) else chunk_c
            t = time.perf_counter()
            state, m = fn(values, state, jnp.int32(start))
            m = distributed.to_host(m)
            train_s += time.perf_counter() - t
            n_iter = m["episode"]["returned"].shape[2]
            steps_run += n_iter * E
            n_run += 1
            env_steps = (start + n_iter) * E
            for i in range(C):
                mi = jax.tree.map(lambda x: x[i], m)
                logs[i].add_steps(mi["episode"], start, E)
                if "update" in mi:
                    learners[i].add(chunk_rows(mi["update"], env_steps, mi.get("updated")))
            if c == trainer.n_chunks - 1 or (every and (c + 1) % every == 0) or (
                    max_chunks is not None and n_run >= max_chunks):
                # episodes first: a checkpoint never runs ahead of the logs (resuming drops episodes past it)
                if main:
                    for i, d in enumerate(folders):
                        logs[i].write_csv(os.path.join(d, "episodes.csv"))
                        learners[i].write_csv(os.path.join(d, "learner.csv"))
                distributed.sync(f"sweep logs written at {env_steps}")
                ckpt.save(env_steps, state, {"chunks_done": c + 1, "env_steps": env_steps, "sweep": sweep,
                                             "train_s_total": prev_train_s + train_s,
                                             "num_processes": distributed.process_count()})
            if verbose:
                print(f"{name}: {env_steps}/{trainer.total_iters * E} env steps per seed "
                      f"({C * S * steps_run / max(train_s, 1e-9):,.0f} steps/s over all)", flush=True)
        ckpt.close()
        finished = done_chunks + n_run == trainer.n_chunks

        ev = None
        if finished and config["eval_episodes"] > 0:
            ek = jax.random.split(jax.random.PRNGKey(config["seed"] + 10_000), S)  # as train.evaluation.evaluate_state
            ev = distributed.to_host(eval_fn(values, state.agent, put(jnp.broadcast_to(ek, (C,) + ek.shape))))
        timing = {"setup_s": time.perf_counter() - t0 - train_s, "compile_s": compile_s, "train_s": train_s,
                  "train_s_total": prev_train_s + train_s, "env_steps_run": steps_run, "configurations": C,
                  "env_steps_per_s_all": C * S * steps_run / max(train_s, 1e-9)}
        summaries = []
        for i, (cfg, folder) in enumerate(zip(configs, folders)):
            s = {"config": cfg, "summary": metrics.summarize(logs[i]), "finished": finished, "timing": timing,
                 "sweep": swept[i]}
            if learners[i].rows:
                s["learner"] = learners[i].summary()
            rows = None
            if ev is not None:
                rows, s["eval"] = eval_rows(jax.tree.map(lambda x: x[i], ev), cfg)
            summaries.append(s)
            if main:
                metrics.write_json(os.path.join(folder, "config.json"), cfg)
                logs[i].write_csv(os.path.join(folder, "episodes.csv"))
                learners[i].write_csv(os.path.join(folder, "learner.csv"))
                metrics.write_json(os.path.join(folder, "summary.json"), s)
                if rows:
                    write_eval_csv(os.path.join(folder, "eval.csv"), rows)
        if main:
            metrics.write_json(os.path.join(out, SWEEP_FILE), {
                "base": config, "sweep": sweep, "finished": finished, "timing": timing,
                "configurations": [{"folder": os.path.join("configs", n), "values": s["sweep"],
                                    "last": {k: v["last"] for k, v in s["summary"].items()
                                             if isinstance(v, dict) and "last" in v}}
                                   for n, s in zip(names, summaries)]})
            if finished:
                _sweep_figures(out, names, config)
        distributed.sync("sweep finished")
        return {"state": state, "configs": configs, "summaries": summaries, "names": names, "finished": finished}
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
