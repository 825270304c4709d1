"""Host-side driver: compile once, run the chunks, log, checkpoint, resume, evaluate, write the run folder.

Run folder layout (``--out``)::

    config.json       the resolved configuration
    episodes.csv      one row per finished training episode and seed (jaxsmarl.metrics.EPISODE_FIELDS)
    summary.json      first/last-10% statistics with 95% bootstrap CIs across seeds, timing, evaluation
    learner.csv       per chunk, seed and agent: the Lagrange multiplier and cost estimate (jaxsmarl.learner_log)
    eval.csv          greedy evaluation episodes per seed (if eval_episodes > 0)
    checkpoints/<env steps>/   orbax checkpoints of the whole training state (all seeds)

The chunk loop is generic (any :class:`train.trainer.Trainer`); resuming restores the newest checkpoint and
feeds it to the same compiled chunk, so the result is bit-identical to an uninterrupted run.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxsmarl import metrics
from jaxsmarl.checkpoints import Checkpointer, CheckpointError
from jaxsmarl.learner_log import LearnerLog, chunk_rows
from train import distributed
from train.config import RESUME_FREE, read_run_config
from train.lock import LOCK_NAME, RunLock
from train.trainer import make_train, seed_keys

__all__ = ["run", "restore_run", "evaluate_checkpoint", "use_all_cpu_cores", "seed_sharding", "seed_parallel",
           "seed_loop"]


# XLA:CPU flags for the training programs. YNNPACK's "reduce" fusions run the reductions over the batch axis of
# small networks' backward passes (LayerNorm scale/bias and bias gradients) far slower than XLA's own loop
# emitter. Numerics are unchanged up to summation order.
# The concurrency-optimised scheduler orders a program's kernels for running independent ones side by side on the
# intra-op threads; each seed shard runs on one core, and the default order keeps a network's activations in
# cache. The order of the kernels changes, not what they compute. Measurements: docs/performance.md.
XLA_CPU_FLAGS = ("--xla_cpu_experimental_ynn_fusion_type=-reduce",
                 "--xla_cpu_enable_concurrency_optimized_scheduler=false")
# The first jaxlib that knows both flags (the YNNPACK one is the newer; its fusions are on by default from 0.10.2);
# an older XLA aborts the process on an unknown XLA_FLAGS entry, and has no YNNPACK fusions to turn off.
XLA_CPU_FLAGS_SINCE = (0, 10, 1)


def _jaxlib_version() -> tuple[int, ...]:
    import re

    import jaxlib

    version = getattr(jaxlib, "__version__", None) or jaxlib.version.__version__
    return tuple(int(x) for x in re.findall(r"\d+", version)[:3])


def use_all_cpu_cores() -> bool:
    """Expose every CPU core as its own JAX device so that seeds run on all cores in parallel (XLA:CPU runs the
    critics' small matrix products on one thread), and put :data:`XLA_CPU_FLAGS` first in ``XLA_FLAGS`` (unless
    ``XLA_FLAGS`` already sets them, or jaxlib predates them). Must run before JAX executes anything; returns
    success."""
    flags = os.environ.get("XLA_FLAGS", "")
    known = _jaxlib_version() >= XLA_CPU_FLAGS_SINCE
    extra = [f for f in XLA_CPU_FLAGS if known and f.split("=")[0] not in flags]
    if extra:  # ahead of the user's: XLA stops reading XLA_FLAGS at the first word that is not a "--" flag
        os.environ["XLA_FLAGS"] = " ".join(extra + [flags]).strip()
    if "xla_force_host_platform_device_count" in flags:  # the user's device count stands
        return True
    try:
        jax.config.update("jax_num_cpu_devices", max(1, _usable_cores()))
        return True
    except RuntimeError:
        return False


def _usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, e.g. under ``taskset`` or a SLURM allocation)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def seed_sharding(num_seeds: int):
    """Split the seed axis over the devices (as many as divide ``num_seeds``); None for one device. In a
    multi-process run the mesh holds every device of every process, and ``num_seeds`` must be a multiple of their
    number (each process runs the seeds of its own devices)."""
    devices = jax.devices()
    if jax.process_count() > 1 and num_seeds % len(devices):
        raise ValueError(f"num_seeds ({num_seeds}) must be a multiple of the {len(devices)} devices of the "
                         f"{jax.process_count()} processes in a multi-process run (each device runs as many seeds); "
                         f"e.g. --seeds {(num_seeds // len(devices) + 1) * len(devices)}")
    n = math.gcd(num_seeds, len(devices))
    if n <= 1:
        return None
    return NamedSharding(Mesh(np.array(devices[:n]), ("seeds",)), PartitionSpec("seeds"))


def seed_loop(fn, in_axes=0):
    """``jax.vmap(fn, in_axes)`` computed one seed after another (``lax.map``): the same values up to round-off,
    each seed by the unbatched program (so, from two seeds up, a seed's result does not depend on the others).
    ``in_axes``: 0 or None per argument."""
    def run(*args):
        axes = tuple(in_axes) if isinstance(in_axes, (tuple, list)) else (in_axes,) * len(args)
        if len(axes) != len(args) or any(a not in (0, None) for a in axes):
            raise ValueError(f"seed_loop: in_axes must be 0 or None per argument, got {in_axes!r}")
        mapped = tuple(x for x, a in zip(args, axes) if a == 0)

        def one(xs):
            it = iter(xs)
            return fn(*(next(it) if a == 0 else x for x, a in zip(args, axes)))

        return jax.lax.map(one, mapped)

    return run


def seed_parallel(fn, num_seeds: int, in_axes=0, donate_argnums=(), sequential: bool = False):
    """``jit(vmap(fn, in_axes))`` over ``num_seeds`` seeds, the seeds split over the devices of
    :func:`seed_sharding`: each device runs its own seeds as an independent program (``shard_map``), and every
    output is sharded along the seed axis.

    Not ``jit(vmap(fn), out_shardings=...)``: the SPMD partitioner then keeps the devices of one program in
    lock-step, e.g. a ``while_loop`` whose trip count depends on the seed (the envs' ``sparse_map``) gets an
    all-reduce over devices in its condition at every trip; seeds are independent, so nothing should cross
    devices (and an XLA:CPU collective parks a thread of the 2-thread intra-op pool while it waits).

    ``sequential``: a device runs its seeds one after another (:func:`seed_loop`) instead of batched: on XLA:CPU
    the batched update runs slower than the same work seed by seed, and the rollout costs the same either way
    (docs/performance.md).
    """
    sharding = seed_sharding(num_seeds)
    vfn = seed_loop(fn, in_axes) if sequential else jax.vmap(fn, in_axes=in_axes)
    if sharding is None:
        return jax.jit(vfn, donate_argnums=donate_argnums)
    seeds, rep = PartitionSpec("seeds"), PartitionSpec()
    axes = in_axes if isinstance(in_axes, (tuple, list)) else (in_axes,)
    specs = tuple(rep if a is None else seeds for a in axes)
    if not isinstance(in_axes, (tuple, list)):
        specs = specs[0]
    # check_vma off: every value is per device anyway (all outputs are split along the seeds), and the check
    # rejects scans whose carry starts replicated (a constant) and becomes per-device.
    return jax.jit(jax.shard_map(vfn, mesh=sharding.mesh, in_specs=specs, out_specs=seeds, check_vma=False),
                   donate_argnums=donate_argnums)


def _print(msg: str, live: bool, end: str = "\n") -> None:
    if live and sys.stdout.isatty():
        sys.stdout.write("\r\033[K" + msg + ("" if end == "\r" else end))
    else:
        sys.stdout.write(msg + "\n")
    sys.stdout.flush()


_PROGRAMS: dict[str, dict] = {}


def _program(config: dict, env=None) -> dict:
    """The trainer and its jitted functions for ``config``; memoised per process (when ``env`` is None) so that
    running one configuration again (resume, evaluation, tests) reuses the compiled program."""
    key = json.dumps({k: v for k, v in config.items() if k != "checkpoint_every"}, sort_keys=True)
    if env is None and key in _PROGRAMS:
        return _PROGRAMS[key]
    trainer = make_train(config, env)
    S = config["num_seeds"]
    prog = {
        "trainer": trainer, "sharding": seed_sharding(S), "compiled": {},
        "init": seed_parallel(trainer.init, S),
        "chunk": seed_parallel(trainer.run_chunk, S, in_axes=(0, None), donate_argnums=0,
                               sequential=trainer.seeds_in_sequence),
        "tail": (seed_parallel(trainer.run_tail, S, in_axes=(0, None), donate_argnums=0,
                               sequential=trainer.seeds_in_sequence)
                 if trainer.run_tail is not None else None),
        "evaluate": seed_parallel(trainer.evaluate, S),
    }
    if env is None:
        _PROGRAMS[key] = prog
    return prog


def _compiled_chunks(prog: dict, state) -> dict:
    """Ahead-of-time compiled chunk (and tail chunk) for states shaped and placed like ``state``."""
    if not prog["compiled"]:
        prog["compiled"]["chunk"] = prog["chunk"].lower(state, jnp.int32(0)).compile()
        if prog["tail"] is not None:
            prog["compiled"]["tail"] = prog["tail"].lower(state, jnp.int32(0)).compile()
    return prog["compiled"]


def _check_out_dir(out: str, resume: bool, overwrite: bool) -> None:
    ckpt = os.path.join(out, "checkpoints")
    has_run = os.path.exists(os.path.join(out, "config.json")) or os.path.isdir(ckpt)
    if resume:
        if not os.path.isdir(ckpt):
            raise ValueError(f"--resume: no checkpoints in {out}; start a new run without --resume")
        return
    if has_run and not overwrite:
        raise ValueError(f"{out} already holds a run; pass --resume to continue it, --overwrite to replace it, "
                         "or choose another --out")


def _same_config(saved: dict, cfg: dict) -> None:
    # total_steps is checked by _check_new_budget
    ignore = (*RESUME_FREE, "total_steps")
    diff = {k: (saved.get(k), cfg[k]) for k in cfg if k not in ignore and saved.get(k) != cfg[k]}
    if diff:
        raise ValueError(f"--resume with a different configuration than the saved run: {diff}; resume with the "
                         "same options (the saved config.json is used when none are given; only --steps, "
                         "--checkpoint-every and --eval-episodes may change) or start a new --out")


def _check_new_budget(saved: dict, config: dict, meta: dict, trainer, env) -> None:
    """Resuming with another ``total_steps`` (e.g. training a finished run further) continues exactly the run a
    fresh one with the new budget would have made, provided the new budget is not below the checkpoint, every
    chunk done so far was a whole one (so chunk ``c`` still starts at ``c * chunk_steps``), and the training state
    has the same shapes (an off-policy buffer holds ``min(buffer_size, total_steps)`` transitions). Nothing else
    in the training programs depends on the budget."""
    done = int(meta["env_steps"])
    if config["total_steps"] < done:
        raise ValueError(f"--resume --steps {config['total_steps']}: the run already has {done} env steps per seed "
                         f"in its newest checkpoint; give at least that many")
    E = config["num_envs"]
    if done != int(meta["chunks_done"]) * trainer.chunk_iters * E:
        raise ValueError(f"--resume --steps {config['total_steps']}: the saved run ended on a partial chunk "
                         f"({done} env steps is not a multiple of chunk_steps={config['chunk_steps']}), so a longer "
                         f"run would not continue it exactly; start a new --out")
    key = jax.random.PRNGKey(0)
    old_shapes = jax.eval_shape(_program(saved, env)["trainer"].init, key)
    new_shapes = jax.eval_shape(trainer.init, key)
    if jax.tree.structure(old_shapes) != jax.tree.structure(new_shapes) or any(
            (a.shape, a.dtype) != (b.shape, b.dtype)
            for a, b in zip(jax.tree.leaves(old_shapes), jax.tree.leaves(new_shapes))):
        raise ValueError(f"--resume --steps {config['total_steps']}: the training state would change shape (a replay "
                         f"buffer holds min(buffer_size, total_steps) = min({saved.get('buffer_size')}, "
                         f"{saved['total_steps']}) transitions in the saved run); start a new --out with the longer "
                         f"budget, or set buffer_size to at most {saved['total_steps']} there")


def run(config: dict, out: str, *, resume: bool = False, overwrite: bool = False, env=None, verbose: bool = True,
        max_chunks: int | None = None) -> dict:
    """Train ``config["num_seeds"]`` seeds into ``out``. ``max_chunks`` stops early (for tests: an interruption).

    Returns ``{"state": final state (all seeds), "log": EpisodeLog, "summary": dict}``.
    """
    out = os.path.abspath(out)
    main = distributed.is_main()  # in a multi-process run, process 0 holds the lock and writes the files
    lock = RunLock(out).acquire() if main and os.path.isdir(out) else None  # a live run's folder is refused first
    try:
        _check_out_dir(out, resume, overwrite)
        distributed.sync("run folder checked")  # every process has seen the folder before process 0 changes it
        if main:
            os.makedirs(out, exist_ok=True)
            lock = lock or RunLock(out).acquire()
            if overwrite and not resume:
                _clear_run_dir(out)
        distributed.sync("run folder ready")
        return _run_locked(config, out, resume=resume, env=env, verbose=verbose and main, max_chunks=max_chunks)
    finally:
        if lock is not None:
            lock.release()


def _clear_run_dir(out: str) -> None:
    """Delete everything in run folder ``out`` but its lock file (held by this process)."""
    import shutil

    for name in os.listdir(out):
        if name == LOCK_NAME:
            continue
        path = os.path.join(out, name)
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path)
        else:
            os.remove(path)


def _check_process_count(ckpt: Checkpointer, meta: dict | None = None) -> None:
    """A run resumes with as many processes as wrote its checkpoints (``meta`` of the restored one, or the newest
    one's when it is readable): each process restores the seeds of its own devices."""
    if meta is None:
        try:
            meta = ckpt.meta()
        except (CheckpointError, FileNotFoundError):
            return  # unreadable: restore_valid finds an intact one, checked afterwards
    saved, now = int(meta.get("num_processes", 1)), distributed.process_count()
    if saved != now:
        raise ValueError(f"--resume: the run was trained by {saved} process{'es' if saved > 1 else ''} and this "
                         f"is {now}; resume it with --num-processes {saved} (the seeds of each process's devices "
                         f"are in its checkpoints), or start a new --out")


def _set_aside(out: str, step: int) -> str:
    """Move damaged checkpoint ``step`` out of ``checkpoints/`` (so the resumed run can write that step again)
    into ``damaged_checkpoints/``, where it stays for inspection."""
    src = os.path.join(out, "checkpoints", str(step))
    base = os.path.join(out, "damaged_checkpoints", str(step))
    dst, i = base, 1
    while os.path.exists(dst):
        dst, i = f"{base}.{i}", i + 1
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    os.replace(src, dst)
    return dst


def _run_locked(config: dict, out: str, *, resume: bool, env, verbose: bool, max_chunks: int | None) -> dict:
    cfg_path = os.path.join(out, "config.json")
    if resume:
        saved_cfg = read_run_config(out)
        _same_config(saved_cfg, config)

    name = f"{config['scenario']}/{config['algo']} x{config['num_seeds']}"
    S, E = config["num_seeds"], config["num_envs"]
    t0 = time.perf_counter()
    prog = _program(config, env)
    trainer, sharding = prog["trainer"], prog["sharding"]

    ckpt = Checkpointer(os.path.join(out, "checkpoints"), max_to_keep=2)
    if resume:
        try:  # before anything is compiled
            _check_process_count(ckpt)
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
            _check_process_count(ckpt, meta)
            if saved_cfg["total_steps"] != config["total_steps"]:
                _check_new_budget(saved_cfg, config, meta, trainer, env)
        except ValueError:
            ckpt.close()
            raise
        for e in skipped:  # said even when quiet: the newest checkpoint is not the one resumed
            if main:
                _print(f"{name}: skipped checkpoint {e.step} ({e.reason}); moved it to {_set_aside(out, e.step)}",
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
            _print(f"{name}: resumed from {out}/checkpoints at {meta['env_steps']} env steps{unchecked}", False)
    if main:  # after the resume checks: a refused resume leaves the saved run as it was
        metrics.write_json(cfg_path, config)
    state = distributed.to_global(state, sharding) if multi else jax.device_put(state, sharding)
    jax.block_until_ready(state)

    t_compile = time.perf_counter()
    compiled = _compiled_chunks(prog, state) if done_chunks < trainer.n_chunks else {}
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
        new = log.add_steps(m["episode"], start_iter, E)
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
            _print(line, True, end="\n" if is_last else "\r")
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
            _write_eval_csv(os.path.join(out, "eval.csv"), ev["rows"])
    if multi:
        timing["num_processes"] = distributed.process_count()
        timing["num_devices"] = len(jax.devices())
    if main:
        metrics.write_json(summary_path, summary)
    ckpt.close()
    distributed.sync("run finished")
    if verbose and finished:
        _print(_final_report(name, summary), False)
    return {"state": state, "log": log, "summary": summary}


def evaluate_state(trainer, state, config: dict, eval_fn=None, sharding=None) -> dict:
    """Greedy evaluation of every seed's agent: ``eval_episodes`` episodes each (vmapped over seeds; ``sharding``:
    the seeds' placement, needed when it spans several processes)."""
    key = jax.random.PRNGKey(config["seed"] + 10_000)
    keys = jax.random.split(key, config["num_seeds"])
    eval_fn = jax.jit(jax.vmap(trainer.evaluate)) if eval_fn is None else eval_fn
    if sharding is not None and not sharding.is_fully_addressable:
        keys = distributed.to_global(keys, sharding)
    rec = distributed.to_host(eval_fn(state.agent, keys))  # [S, N]
    rows, summ = eval_rows(rec, config)
    return {"rows": rows, "summary": summ}


def eval_rows(rec: dict, config: dict) -> tuple[list[dict], dict]:
    """``(rows, summary)`` of the greedy evaluation records ``rec`` (host arrays ``[S, N]``): one row per seed and
    episode, and per field the per-seed means with a bootstrap interval across seeds."""
    rows = []
    n = config["eval_episodes"]
    for s in range(config["num_seeds"]):
        for e in range(n):
            row = {"seed": s, "episode": e, "finished": bool(rec["returned"][s, e])}
            row.update({k: float(rec[k][s, e]) for k in metrics.EPISODE_FIELDS})
            rows.append(row)
    summ = {}
    for k in metrics.EPISODE_FIELDS:
        per_seed = [float(np.mean(rec[k][s, :n])) for s in range(config["num_seeds"])]
        summ[k] = {"mean_ci": metrics.bootstrap_ci(per_seed), "per_seed": per_seed}
    summ["unfinished_episodes"] = int(n * config["num_seeds"] - np.sum(rec["returned"][:, :n]))
    return rows, summ


def _write_eval_csv(path: str, rows: list[dict]) -> None:
    import csv

    if not rows:
        return
    with metrics.atomic_open(path, newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def restore_run(run_dir: str, step: int | None = None):
    """``(config, trainer, state, meta)`` of run folder ``run_dir``: its configuration (later-added keys at their
    defaults), the trainer rebuilt from it (nothing is compiled) and the training state of all seeds from the
    newest checkpoint (or ``step``)."""
    ckpt_dir = os.path.join(run_dir, "checkpoints")
    config = read_run_config(run_dir)
    if not os.path.isdir(ckpt_dir):
        raise ValueError(f"{run_dir} is not a run folder (needs config.json and checkpoints/, as written by "
                         "python -m train)")
    trainer = make_train(config)
    template = jax.eval_shape(jax.vmap(trainer.init), seed_keys(config))
    return config, trainer, *_restore_checked(ckpt_dir, step, template)


def _restore_checked(ckpt_dir: str, step: int | None, template) -> tuple[Any, dict]:
    """``(state, meta)`` of checkpoint ``step`` in ``ckpt_dir`` if it is intact (else CheckpointError); for None
    the newest intact one, saying on stderr which newer ones were skipped and why."""
    skipped: list[CheckpointError] = []
    with Checkpointer(ckpt_dir) as ckpt:
        if ckpt.latest_step() is None:
            raise ValueError(f"{ckpt_dir} holds no complete checkpoint yet")
        if step is not None:
            return ckpt.restore(step, template)
        _, state, meta = ckpt.restore_valid(template, skipped.append)
    for e in skipped:
        print(f"skipped checkpoint {e.step} of {ckpt_dir} ({e.reason}); using {meta.get('env_steps')}",
              file=sys.stderr)
    return state, meta


def evaluate_checkpoint(out: str, episodes: int | None = None, step: int | None = None, env=None) -> dict:
    """Greedy evaluation of the checkpoint in run folder ``out`` (newest, or ``step``)."""
    config = read_run_config(out)
    if episodes is not None:
        config["eval_episodes"] = int(episodes)
    prog = _program(config, env)
    template = jax.eval_shape(prog["init"], seed_keys(config))
    state, meta = _restore_checked(os.path.join(out, "checkpoints"), step, template)
    ev = evaluate_state(prog["trainer"], distributed.to_global(state, prog["sharding"]), config, prog["evaluate"],
                        prog["sharding"])
    ev["env_steps"] = meta.get("env_steps")
    return ev


def _final_report(name: str, summary: dict) -> str:
    s, t = summary["summary"], summary["timing"]
    f = lambda k: "{:.2f} [{:.2f}, {:.2f}]".format(*s[k]["last"])
    lines = [f"{name}: {t['env_steps_run']} env steps/seed in {metrics.format_duration(t['train_s'])} "
             f"({t['env_steps_per_s_all_seeds']:,.0f} steps/s over all seeds; compile {t['compile_s']:.1f}s)",
             f"  last 10% of episodes (mean [95% CI] across seeds): return L {f('leader_return')} "
             f"F {f('follower_return')} T {f('total_return')} | crash {f('crash')}"]
    if "eval" in summary:
        e = summary["eval"]
        g = lambda k: "{:.2f} [{:.2f}, {:.2f}]".format(*e[k]["mean_ci"])
        lines.append(f"  greedy evaluation: return L {g('leader_return')} F {g('follower_return')} | "
                     f"crash {g('crash')}")
    return "\n".join(lines)
