"""Greedy evaluation of a run's agents: every seed's policy for ``eval_episodes`` episodes, the rows of
``eval.csv`` and their summary (per-seed means with a bootstrap interval across seeds)."""

from __future__ import annotations

import csv
import os

import jax
import numpy as np

from jaxsmarl import metrics
from train import distributed
from train.config import read_run_config
from train.programs import program
from train.restore import restore_checked
from train.trainer import seed_keys

__all__ = ["evaluate_state", "eval_rows", "write_eval_csv", "evaluate_checkpoint"]


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
    fields = metrics.record_fields(rec)
    for s in range(config["num_seeds"]):
        for e in range(n):
            row = {"seed": s, "episode": e, "finished": bool(rec["returned"][s, e])}
            row.update({k: float(rec[k][s, e]) for k in fields})
            rows.append(row)
    summ = {}
    for k in fields:
        per_seed = [float(np.mean(rec[k][s, :n])) for s in range(config["num_seeds"])]
        summ[k] = {"mean_ci": metrics.bootstrap_ci(per_seed), "per_seed": per_seed}
    summ["unfinished_episodes"] = int(n * config["num_seeds"] - np.sum(rec["returned"][:, :n]))
    return rows, summ


def write_eval_csv(path: str, rows: list[dict]) -> None:
    if not rows:
        return
    with metrics.atomic_open(path, newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def evaluate_checkpoint(out: str, episodes: int | None = None, step: int | None = None, env=None) -> dict:
    """Greedy evaluation of the checkpoint in run folder ``out`` (newest, or ``step``)."""
    config = read_run_config(out)
    if episodes is not None:
        config["eval_episodes"] = int(episodes)
    prog = program(config, env)
    template = jax.eval_shape(prog["init"], seed_keys(config))
    state, meta = restore_checked(os.path.join(out, "checkpoints"), step, template)
    ev = evaluate_state(prog["trainer"], distributed.to_global(state, prog["sharding"]), config, prog["evaluate"],
                        prog["sharding"])
    ev["env_steps"] = meta.get("env_steps")
    return ev
