"""The learner's diagnostics per training chunk: each agent's Lagrange multiplier and cost estimate.

One row per chunk, seed and agent (``learner.csv`` in the run folder): ``lambda`` is the multiplier after the
chunk's last update, ``cost_estimate`` the cost the learner's constraint reads, averaged over the chunk's updates:
the mean cost-critic prediction on each sampled batch (CSQ: at the stored actions; the constrained MADDPG
variants: at the current actors' actions, what their multiplier step reads) or the episode-cost estimate ``J_c``
of each rollout (MAPPO-L, MACPO). A learner without a multiplier (CSQ, MACPO) or without a cost
critic (the unconstrained variants) leaves that column empty.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping
from typing import Any

import numpy as np

from jaxsmarl.metrics import atomic_open

__all__ = ["FIELDS", "SOURCES", "chunk_rows", "LearnerLog"]

FIELDS = ("lambda", "cost_estimate")
# the update-info keys each field is read from, by learner family
SOURCES = {"lambda": ("lam", "lagrange"), "cost_estimate": ("g_actor", "g_mean", "episode_cost")}


def _pick(update: Mapping[str, Any], field: str):
    for key in SOURCES[field]:
        if key in update:
            return np.asarray(update[key], np.float64)
    return None


def chunk_rows(update: Mapping[str, Any], env_steps: int, updated: Any = None) -> list[dict]:
    """Rows for one chunk from its update info (arrays ``[seeds, updates, agents]``) and ``updated``
    (bool ``[seeds, updates]``, or None when every entry is an update). Seeds without an update in the chunk
    (still warming up) give no rows."""
    values = {f: _pick(update, f) for f in FIELDS}
    present = [v for v in values.values() if v is not None]
    if not present:
        return []
    n_seeds, n_upd, n_agents = present[0].shape[:3]
    mask = np.ones((n_seeds, n_upd), bool) if updated is None else np.asarray(updated, bool).reshape(n_seeds, n_upd)
    rows = []
    for s in range(n_seeds):
        idx = np.flatnonzero(mask[s])
        if idx.size == 0:
            continue
        for i in range(n_agents):
            row = {"seed": s, "env_steps": int(env_steps), "agent": i}
            lam, cost = values["lambda"], values["cost_estimate"]
            row["lambda"] = float(lam[s, idx[-1], i]) if lam is not None else ""
            row["cost_estimate"] = float(np.mean(cost[s, idx, i])) if cost is not None else ""
            rows.append(row)
    return rows


class LearnerLog:
    """All rows of a run; written whole to a temporary file and renamed, so the file is never half-written."""

    COLUMNS = ("seed", "env_steps", "agent") + FIELDS

    def __init__(self, rows=()):
        self.rows: list[dict] = list(rows)

    def add(self, rows: list[dict]) -> None:
        self.rows.extend(rows)

    def truncate(self, max_env_steps: int) -> None:
        """Drop rows of chunks after ``max_env_steps`` (a resumed run replays them)."""
        self.rows = [r for r in self.rows if r["env_steps"] <= max_env_steps]

    def write_csv(self, path: str | os.PathLike) -> None:
        if not self.rows:
            return
        with atomic_open(path, newline="") as f:  # flushed to disk; a failed write leaves no temporary file
            w = csv.DictWriter(f, fieldnames=list(self.COLUMNS))
            w.writeheader()
            w.writerows(self.rows)

    @classmethod
    def read_csv(cls, path: str | os.PathLike) -> "LearnerLog":
        if not os.path.exists(path):
            return cls()
        rows = []
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                row = {"seed": int(r["seed"]), "env_steps": int(r["env_steps"]), "agent": int(r["agent"])}
                row.update({k: (float(r[k]) if r[k] != "" else "") for k in FIELDS})
                rows.append(row)
        return cls(rows)

    def series(self, field: str, agent: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Per seed: ``(env_steps, value)`` of ``field`` for ``agent``, in chunk order (empty if not logged)."""
        out: dict[int, tuple[list, list]] = {}
        for r in self.rows:
            if r["agent"] == agent and r[field] != "":
                xs, ys = out.setdefault(r["seed"], ([], []))
                xs.append(r["env_steps"])
                ys.append(r[field])
        return {s: (np.asarray(x), np.asarray(y)) for s, (x, y) in sorted(out.items())}

    def num_agents(self) -> int:
        return 1 + max((r["agent"] for r in self.rows), default=-1)

    def summary(self, frac: float = 0.1) -> dict:
        """Per field and agent: the last chunk's value per seed (lambda) or its mean over the last ``frac`` of the
        chunks (cost estimate), with the mean and 95% bootstrap interval across seeds."""
        from jaxsmarl.metrics import bootstrap_ci

        out: dict[str, Any] = {}
        for field in FIELDS:
            per_agent = []
            for i in range(self.num_agents()):
                series = self.series(field, i)
                if not series:
                    continue
                per_seed = []
                for _, (_, y) in series.items():
                    k = max(1, int(np.ceil(frac * len(y))))
                    per_seed.append(float(y[-1]) if field == "lambda" else float(np.mean(y[-k:])))
                per_agent.append({"agent": i, "per_seed": per_seed, "mean_ci": bootstrap_ci(per_seed)})
            if per_agent:
                out[field] = per_agent
        return out
