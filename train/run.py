"""Host-side driver: compile once, run the chunks, log, checkpoint, resume, evaluate, write the run folder.

Run folder layout (``--out``)::

    config.json       the resolved configuration
    episodes.csv      one row per finished training episode and seed (jaxsmarl.metrics.EPISODE_FIELDS; the
                      traffic scenarios add per-agent returns and costs and the average speed)
    summary.json      first/last-10% statistics with 95% bootstrap CIs across seeds, timing, evaluation
    learner.csv       per chunk, seed and agent: the Lagrange multiplier and cost estimate (jaxsmarl.learner_log)
    eval.csv          greedy evaluation episodes per seed (if eval_episodes > 0)
    checkpoints/<env steps>/   orbax checkpoints of the whole training state (all seeds)

Its parts: :mod:`train.run_folder` (checks before and while resuming), :mod:`train.programs` (the compiled
programs), :mod:`train.parallel` (seeds over devices), :mod:`train.evaluation`, :mod:`train.restore`,
:mod:`train.console`.

The chunk loop is generic (any :class:`train.trainer.Trainer`); resuming restores the newest checkpoint and
feeds it to the same compiled chunk, so the result is bit-identical to an uninterrupted run.
"""

from __future__ import annotations

import json
import os
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxsmarl import metrics
from jaxsmarl.checkpoints import Checkpointer, CheckpointError
from jaxsmarl.learner_log import LearnerLog, chunk_rows
from train import distributed
from train.config import read_run_config
from train.console import final_report, say
from train.evaluation import evaluate_state, write_eval_csv
from train.lock import RunLock
from train.programs import compiled_chunks, program
from train.run_folder import check_new_budget, check_out_dir, check_process_count, clear_run_dir, same_config, set_aside
from train.trainer import seed_keys

__all__ = ["run"]


def run(config: dict, out: str, *, resume: bool = False, overwrite: bool = False, env=None, verbose: bool = True,
        max_chunks: int | None = None) -> dict:
    """Train ``config["num_seeds"]`` seeds into ``out``. ``max_chunks`` stops early (for tests: an interruption).

    Returns ``{"state": final state (all seeds), "log": EpisodeLog, "summary": dict}``.
    """
    out = os.path.abspath(out)
    main = distributed.is_main()  # in a multi-process run, process 0 holds the lock and writes the files
    lock = RunLock(out).acquire() if main and os.path.isdir(out) else None  # a live run's folder is refused first
    try:
        check_out_dir(out, resume, overwrite)
        distributed.sync("run folder checked")  # every process has seen the folder before process 0 changes it
        if main:
            os.makedirs(out, exist_ok=True)
            lock = lock or RunLock(out).acquire()
            if overwrite and not resume:
                clear_run_dir(out)
        distributed.sync("run folder ready")
        return _run_locked(config, out, resume=resume, env=env, verbose=verbose and main, max_chunks=max_chunks)
    finally:
        if lock is not None:
            lock.release()


def _run_locked(config: dict, out: str, *, resume: bool, env, verbose: bool, max_chunks: int | None) -> dict:
    cfg_path = os.path.join(out, "config.json")
    if resume:
        saved_cfg = read_run_config(out)
        same_config(saved_cfg, config)

    name = f"{config['scenario']}/{config['algo']} x{config['num_seeds']}"
    S, E = config["num_seeds"], config["num_envs"]
    t0 = time.perf_counter()
    prog = program(config, env)
    trainer, sharding = prog["trainer"], prog["sharding"]

    ckpt = Checkpointer(os.path.join(out, "checkpoints"), max_to_keep=2)
    if resume:
        try:  # before anything is compiled
            check_process_count(ckpt)
        except ValueError:
            ckpt.close()
            raise
    csv_path = os.path.join(out, "episodes.csv")
    learner_path = os.path.join(out, "learner.csv")
    main = distributed.is_main()
    multi = distributed.process_count() > 1
    keys = seed_keys(config)
    state = prog["init"](distributed.to_global(keys, sharding) if multi else keys)
    done_chunks = 0
    log = metrics.EpisodeLog(S)
    learner = LearnerLog()
    prev = {"train_s_total": 0.0, "compile_s_total": 0.0, "segments": 0}  # earlier segments of a resumed run
    if resume:
        skipped: list[CheckpointError] = []
        try:  # the newest checkpoint that passes its digests
            step, state, meta = ckpt.restore_valid(state, skipped.append)
            check_process_count(ckpt, meta)
            if saved_cfg["total_steps"] != config["total_steps"]:
                check_new_budget(saved_cfg, config, meta, trainer, env)
        except ValueError:
            ckpt.close()
            raise
        for e in skipped:  # said even when quiet: the newest checkpoint is not the one resumed
            if main:
                say(f"{name}: skipped checkpoint {e.step} ({e.reason}); moved it to {set_aside(out, e.step)}",
                       False)
        distributed.sync("damaged checkpoints set aside")
        done_chunks = int(meta["chunks_done"])
        prev = {k: meta.get(k, v) for k, v in prev.items()}
        if os.path.exists(csv_path):
            log = metrics.EpisodeLog.read_csv(csv_path, S)
        log.truncate(int(meta["env_steps"]))  # episodes logged after the checkpoint are replayed
        learner = LearnerLog.read_csv(learner_path)
        learner.truncate(int(meta["env_steps"]))
        if verbose:
            unchecked = " (saved without digests: not verified)" if meta.get("verified") is False else ""
            say(f"{name}: resumed from {out}/checkpoints at {meta['env_steps']} env steps{unchecked}", False)
    if main:  # after the resume checks: a refused resume leaves the saved run as it was
        metrics.write_json(cfg_path, config)
    state = distributed.to_global(state, sharding) if multi else jax.device_put(state, sharding)
    jax.block_until_ready(state)

    t_compile = time.perf_counter()
    compiled = compiled_chunks(prog, state) if done_chunks < trainer.n_chunks else {}
    compile_s = time.perf_counter() - t_compile
    setup_s = time.perf_counter() - t0

    total_steps = trainer.total_iters * E
    ckpt_every_chunks = (config["checkpoint_every"] // config["chunk_steps"]) if config["checkpoint_every"] else 0
    train_s = 0.0
    steps_run = 0
    last_meta: dict[str, Any] = {}
    n_run = 0
    for c in range(done_chunks, trainer.n_chunks):
        if max_chunks is not None and n_run >= max_chunks:
            break
        start_iter = c * trainer.chunk_iters
        fn = compiled["tail"] if (trainer.run_tail is not None and c == trainer.n_chunks - 1) else compiled["chunk"]
        t = time.perf_counter()
        state, m = fn(state, jnp.int32(start_iter))
        m = distributed.to_host(m) if multi else jax.device_get(m)
        dt = time.perf_counter() - t
        train_s += dt
        n_iter = m["episode"]["returned"].shape[1]
        steps_run += n_iter * E
        n_run += 1
        log.add_steps(m["episode"], start_iter, E)
        env_steps = (start_iter + n_iter) * E
        if "update" in m:
            learner.add(chunk_rows(m["update"], env_steps, m.get("updated")))
        last_meta = {"chunks_done": c + 1, "env_steps": env_steps,
                     "train_s_total": prev["train_s_total"] + train_s,
                     "compile_s_total": prev["compile_s_total"] + compile_s, "segments": prev["segments"] + 1,
                     "num_processes": distributed.process_count(), "num_devices": len(jax.devices())}
        is_last = c == trainer.n_chunks - 1
        if is_last or (ckpt_every_chunks and (c + 1) % ckpt_every_chunks == 0) or (
                max_chunks is not None and n_run >= max_chunks):
            # episodes first: a checkpoint never runs ahead of the log (resuming drops logged episodes past it)
            if main:
                log.write_csv(csv_path)
                learner.write_csv(learner_path)
            distributed.sync(f"log written at {env_steps}")
            ckpt.save(env_steps, state, last_meta)  # every process writes its own seeds' shards
        if verbose:
            recent = [r for r in log.rows if r["end_step"] > env_steps - config["chunk_steps"]]
            sps = steps_run / max(train_s, 1e-9)
            eta = (total_steps - env_steps) / max(sps, 1e-9)
            explore = (np.ravel(np.asarray(jax.tree.leaves(m["explore"])[0])[0, -1]).tolist()
                       if "explore" in m and jax.tree.leaves(m["explore"]) else None)
            line = metrics.progress_line(name, env_steps, total_steps, sps, eta, recent, eps=explore)
            say(line, True, end="\n" if is_last else "\r")
    chunks_done = last_meta.get("chunks_done", done_chunks)
    finished = chunks_done == trainer.n_chunks
    if main:
        log.write_csv(csv_path)
        learner.write_csv(learner_path)

    timing = {"setup_s": setup_s, "compile_s": compile_s, "train_s": train_s, "env_steps_run": steps_run,
              "env_steps_per_s_per_seed": steps_run / max(train_s, 1e-9),
              "env_steps_per_s_all_seeds": S * steps_run / max(train_s, 1e-9),
              # over every segment of a resumed run (checkpoint metadata carries the totals)
              "train_s_total": prev["train_s_total"] + train_s, "compile_s_total": prev["compile_s_total"] + compile_s,
              "segments": prev["segments"] + (1 if steps_run else 0)}
    summary_path = os.path.join(out, "summary.json")
    if steps_run == 0 and os.path.exists(summary_path):  # resumed an already finished run: keep its timing
        with open(summary_path) as f:
            timing = json.load(f).get("timing", timing)
    summary = {"config": config, "summary": metrics.summarize(log), "finished": finished, "timing": timing}
    if learner.rows:
        summary["learner"] = learner.summary()
    if finished and config["eval_episodes"] > 0:
        ev = evaluate_state(trainer, state, config, prog["evaluate"], sharding)
        summary["eval"] = ev["summary"]
        if main:
            write_eval_csv(os.path.join(out, "eval.csv"), ev["rows"])
    if multi:
        timing["num_processes"] = distributed.process_count()
        timing["num_devices"] = len(jax.devices())
    if main:
        metrics.write_json(summary_path, summary)
    ckpt.close()
    distributed.sync("run finished")
    if verbose and finished:
        say(final_report(name, summary), False)
    return {"state": state, "log": log, "summary": summary}
