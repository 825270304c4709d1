"""Per-episode training metrics: extraction inside jit, host-side tables, summaries with bootstrap CIs.

Inside the compiled loop, :func:`episode_record` turns the auto-reset wrapper's ``info`` of one step into a
fixed-shape record that is valid where ``returned_episode`` is True. On the host, :func:`episodes_from_steps`
turns the stacked records ``[seeds, steps, envs]`` into rows (one per finished episode), :class:`EpisodeLog`
keeps them and writes CSV/JSON, and :func:`summarize` gives the "last 10% of training episodes" statistics
(the window of the authors' records, docs/results.md) with 95% bootstrap intervals ACROSS SEEDS (the
replication unit).
"""

from __future__ import annotations

import contextlib
import csv
import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from typing import Any

import jax.numpy as jnp
import numpy as np

__all__ = [
    "EPISODE_FIELDS", "agent_fields", "record_fields", "episode_record", "episodes_from_steps", "EpisodeLog",
    "bootstrap_ci", "summarize",
    "format_duration", "progress_line", "window_means", "write_json", "atomic_open",
]

# Per-episode columns (after seed / episode / env / step bookkeeping columns).
EPISODE_FIELDS = (
    "leader_return", "follower_return", "total_return", "leader_cost", "follower_cost",
    "crash", "leader_arrived", "follower_arrived", "length", "offroad", "leader_distance", "follower_distance",
)
# Integer-valued columns (0/1 events and lengths).
INT_FIELDS = ("crash", "leader_arrived", "follower_arrived", "length", "offroad")
ID_FIELDS = ("seed", "episode", "env", "end_step")


def agent_fields(num_agents: int) -> tuple[str, ...]:
    """The columns the K-agent traffic scenarios add: each agent's return and cost, then ``speed``."""
    return (tuple(f"return_{k}" for k in range(num_agents)) + tuple(f"cost_{k}" for k in range(num_agents))
            + ("speed",))


def record_fields(keys: Iterable[str]) -> tuple[str, ...]:
    """The episode columns among ``keys`` (a record's or a row's), in table order: :data:`EPISODE_FIELDS`, then
    the per-agent columns of :func:`agent_fields`."""
    keys = set(keys)
    n = 0
    while f"return_{n}" in keys:
        n += 1
    extra = agent_fields(n) if "speed" in keys else ()
    return tuple(k for k in EPISODE_FIELDS + extra if k in keys)


def episode_record(info: Mapping[str, Any]) -> dict:
    """Fixed-shape per-step record from the auto-reset wrapper's ``info`` (valid where ``returned``).

    With K > 2 agents (per-agent statistics ``[..., K]``) the ``leader_*`` columns are agent 0's and the
    ``follower_*`` columns the sum over agents 1..K-1 (``*_arrived``: any of them); ``total_return`` sums all.
    The traffic scenarios' wrapper (:mod:`envs_jax.traffic_autoreset`) also reports each agent's return and cost
    (``return_k``, ``cost_k``) and ``speed``: the mean speed over the agent-steps in which an agent drove (present
    and not yet terminated), docs/algorithms.md."""
    ret = jnp.asarray(info["episode_return"], jnp.float32)
    cost = jnp.asarray(info["episode_cost"], jnp.float32)
    arrived = jnp.asarray(info["episode_arrived"], jnp.float32)
    dist = jnp.asarray(info["episode_distance"], jnp.float32)
    others = lambda x: jnp.sum(x[..., 1:], axis=-1)
    out = {
        "returned": jnp.asarray(info["returned_episode"], bool),
        "leader_return": ret[..., 0], "follower_return": others(ret), "total_return": ret[..., 0] + others(ret),
        "leader_cost": cost[..., 0], "follower_cost": others(cost),
        "crash": jnp.asarray(info["episode_crash"], jnp.float32),
        "leader_arrived": arrived[..., 0], "follower_arrived": jnp.max(arrived[..., 1:], axis=-1),
        "length": jnp.asarray(info["episode_length"], jnp.float32),
        "offroad": jnp.asarray(info["episode_offroad"], jnp.float32),
        "leader_distance": dist[..., 0], "follower_distance": others(dist),
    }
    if "episode_speed_sum" in info:
        for k in range(ret.shape[-1]):
            out[f"return_{k}"] = ret[..., k]
            out[f"cost_{k}"] = cost[..., k]
        speed_sum = jnp.sum(jnp.asarray(info["episode_speed_sum"], jnp.float32), axis=-1)
        active = jnp.sum(jnp.asarray(info["episode_active_steps"], jnp.float32), axis=-1)
        out["speed"] = speed_sum / jnp.maximum(active, 1.0)
    return out


def episodes_from_steps(records: Mapping[str, Any], first_iter: int, num_envs: int, seeds: Sequence[int] | None = None,
                        episode_counts: list[int] | None = None) -> list[dict]:
    """Rows for every finished episode in stacked records ``[S, T, E]``.

    ``first_iter``: global index of the first loop iteration in ``records``; ``end_step`` of a row is the number
    of environment steps (per seed, over all its envs) taken when the episode ended. ``episode_counts``
    (per seed, updated in place) numbers the episodes consecutively across calls.
    """
    returned = np.asarray(records["returned"])
    n_seeds, n_iter, n_envs = returned.shape
    seeds = list(range(n_seeds)) if seeds is None else list(seeds)
    if episode_counts is None:
        episode_counts = [0] * n_seeds
    fields = record_fields(records)
    cols = {k: np.asarray(records[k]) for k in fields}
    rows = []
    for s in range(n_seeds):
        t_idx, e_idx = np.nonzero(returned[s])  # row-major: time first, then env
        for t, e in zip(t_idx, e_idx):
            row = {"seed": seeds[s], "episode": episode_counts[s], "env": int(e),
                   "end_step": int((first_iter + t + 1) * num_envs)}
            for k in fields:
                v = float(cols[k][s, t, e])
                row[k] = int(round(v)) if k in INT_FIELDS else v
            rows.append(row)
            episode_counts[s] += 1
    return rows


class EpisodeLog:
    """All finished training episodes of a run, per seed, with CSV/JSON output."""

    def __init__(self, num_seeds: int, rows: Iterable[dict] = ()):
        self.num_seeds = num_seeds
        self.rows: list[dict] = []
        self.episode_counts = [0] * num_seeds
        for r in rows:
            self.rows.append(r)
            self.episode_counts[r["seed"]] = max(self.episode_counts[r["seed"]], r["episode"] + 1)

    def add_steps(self, records: Mapping[str, Any], first_iter: int, num_envs: int) -> list[dict]:
        new = episodes_from_steps(records, first_iter, num_envs, episode_counts=self.episode_counts)
        self.rows.extend(new)
        return new

    @property
    def fields(self) -> tuple[str, ...]:
        """The episode columns of this log: :data:`EPISODE_FIELDS`, plus the per-agent ones of a traffic run."""
        return record_fields(self.rows[0]) if self.rows else EPISODE_FIELDS

    def per_seed(self, field: str) -> list[np.ndarray]:
        out = [[] for _ in range(self.num_seeds)]
        for r in self.rows:
            out[r["seed"]].append(r[field])
        return [np.asarray(v, np.float64) for v in out]

    def truncate(self, max_end_step: int) -> None:
        """Drop episodes that ended after ``max_end_step`` (used when resuming from a checkpoint)."""
        self.rows = [r for r in self.rows if r["end_step"] <= max_end_step]
        self.episode_counts = [0] * self.num_seeds
        for r in self.rows:
            self.episode_counts[r["seed"]] = max(self.episode_counts[r["seed"]], r["episode"] + 1)

    def write_csv(self, path: str | os.PathLike) -> None:
        with atomic_open(path, newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(ID_FIELDS + self.fields))
            w.writeheader()
            for r in sorted(self.rows, key=lambda r: (r["seed"], r["episode"])):
                w.writerow(r)

    @classmethod
    def read_csv(cls, path: str | os.PathLike, num_seeds: int) -> "EpisodeLog":
        rows = []
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                row = {k: 0 if k in INT_FIELDS else 0.0 for k in EPISODE_FIELDS}  # columns added since: 0
                for k, v in r.items():
                    row[k] = int(v) if k in ID_FIELDS or k in INT_FIELDS else float(v)
                rows.append(row)
        return cls(num_seeds, rows)


def bootstrap_ci(values: Sequence[float], confidence: float = 0.95, n_boot: int = 10000, seed: int = 0):
    """Mean and percentile-bootstrap interval of the mean of ``values`` (one value per seed)."""
    x = np.asarray([v for v in values if np.isfinite(v)], np.float64)
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    if x.size == 1:
        return float(x[0]), float(x[0]), float(x[0])
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, (n_boot, x.size))].mean(axis=1)
    lo, hi = np.quantile(means, [(1 - confidence) / 2, 1 - (1 - confidence) / 2])
    return float(x.mean()), float(lo), float(hi)


def window_means(per_seed: Sequence[np.ndarray], frac: float = 0.1, last: bool = True) -> list[float]:
    """Per seed: the mean over the first/last ``ceil(frac * n)`` episodes (NaN for a seed without episodes)."""
    out = []
    for v in per_seed:
        if len(v) == 0:
            out.append(float("nan"))
            continue
        k = max(1, math.ceil(frac * len(v)))
        out.append(float(np.mean(v[-k:] if last else v[:k])))
    return out


def summarize(log: EpisodeLog, frac: float = 0.1, fields: Sequence[str] | None = None) -> dict:
    """``{field: {"first": (mean, lo, hi), "last": (mean, lo, hi), "last_per_seed": [...]}, "episodes": [...]}``
    for ``fields`` (default: the log's columns)."""
    fields = log.fields if fields is None else fields
    out: dict[str, Any] = {"episodes_per_seed": [int(len(v)) for v in log.per_seed("length")], "window": frac}
    for f in fields:
        ps = log.per_seed(f)
        first, last = window_means(ps, frac, last=False), window_means(ps, frac, last=True)
        out[f] = {"first": bootstrap_ci(first), "last": bootstrap_ci(last), "last_per_seed": last}
    return out


def format_duration(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    h, rem = divmod(seconds, 3600)
    m, s = divmod(rem, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else (f"{m}m{s:02d}s" if m else f"{s}s")


def progress_line(name: str, step: int, total: int, steps_per_s: float, eta_s: float, recent: Sequence[dict],
                  eps: Sequence[float] | None = None, width: int = 20) -> str:
    """``merge/csq ████░░ 40% 8000/20000 | 812 steps/s | ETA 15s | 310 ep: ret L 25.1 F 14.3 | crash 0.12``."""
    frac = min(1.0, step / max(total, 1))
    bar = "#" * int(round(frac * width)) + "." * (width - int(round(frac * width)))
    parts = [f"{name} [{bar}] {100 * frac:3.0f}% {step}/{total}", f"{steps_per_s:,.0f} steps/s/seed",
             f"ETA {format_duration(eta_s)}"]
    if recent:
        m = lambda k: float(np.mean([r[k] for r in recent]))
        parts.append(f"last {len(recent)} ep: ret L {m('leader_return'):.1f} F {m('follower_return'):.1f}"
                     f" | cost L {m('leader_cost'):.2f} F {m('follower_cost'):.2f}"
                     f" | crash {m('crash'):.2f} | len {m('length'):.1f}")
    if eps is not None:
        parts.append("eps " + "/".join(f"{e:.3f}" for e in eps))
    return " | ".join(parts)


def write_json(path: str | os.PathLike, obj: Any) -> None:
    """Atomic JSON write (NaN written as null)."""

    def clean(o):
        if isinstance(o, dict):
            return {str(k): clean(v) for k, v in o.items()}
        if isinstance(o, (list, tuple)):
            return [clean(v) for v in o]
        if isinstance(o, (np.floating, float)):
            return None if not np.isfinite(o) else float(o)
        if isinstance(o, np.integer):
            return int(o)
        if isinstance(o, np.ndarray):
            return clean(o.tolist())
        return o

    with atomic_open(path) as f:
        json.dump(clean(obj), f, indent=2)


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, newline: str | None = None):
    """``with atomic_open(path) as f:`` writes text to ``path.tmp``, flushes it to disk and renames it onto
    ``path`` only once all of it is written; on any error the temporary file is removed and ``path`` keeps its
    old content, so a reader never sees a half-written file."""
    tmp = f"{os.fspath(path)}.tmp"
    try:
        with open(tmp, "w", newline=newline) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.remove(tmp)
        except OSError:
            pass
        raise
