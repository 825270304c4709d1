"""The committed training records (``benchmarks/results/training/``) read as a study, for ``train.report --from``.

A record folder holds what a run folder holds minus the large files: ``config.json``, ``summary.json`` (per-seed
last-10% means and the greedy evaluation), ``eval.csv`` and, instead of checkpoints and the raw ``episodes.csv``,
either ``episodes.csv`` itself (small runs) or ``episodes_binned.csv`` (per-seed means over bins of env steps,
written by ``benchmarks/bin_episodes.py``). :data:`RECORDS` says which folder stands for each scenario x
algorithm; :func:`load_records` turns them into the ``{scenario: {algo: run}}`` dict that :mod:`train.report`
and :mod:`train.figures` draw from:

* the tables take each seed's last-10% mean from ``summary.json`` (``run["final"]``), the same window the report
  computes from a full ``episodes.csv``;
* the curves take one pseudo-episode per (seed, bin) at the bin's centre, weighted by the number of episodes that
  ended in the bin (``run["episodes"]["weight"]``), so re-binning gives the same per-seed means as the raw file.
"""

from __future__ import annotations

import csv
import json
import os

import numpy as np

from train.study import STUDY

__all__ = ["RECORDS", "load_record", "load_records", "missing"]

# (scenario, algo) -> record folder under benchmarks/results/training/. Each is the run at the budget the shipped
# configuration uses (the authors' budget where they recorded one); other folders there (other budgets, the
# authors' coded options) are discussed in docs/results.md.
RECORDS: dict[tuple[str, str], str] = {
    ("merge", "csq"): "merge_csq",
    ("merge", "sq"): "merge_sq",
    ("roundabout", "csq"): "roundabout_csq",
    ("roundabout", "sq"): "roundabout_sq",
    ("intersection", "cs-maddpg"): "intersection_cs-maddpg",
    ("intersection", "s-maddpg"): "intersection_s-maddpg",
    ("intersection", "c-maddpg"): "intersection_c-maddpg",
    ("intersection", "maddpg"): "intersection_maddpg",
    ("intersection", "mappo-l"): "intersection_mappo-l_2m",
    ("intersection", "macpo"): "intersection_macpo",
    ("racetrack", "cs-maddpg"): "racetrack_cs-maddpg_gpu",
    ("racetrack", "s-maddpg"): "racetrack_s-maddpg",
    ("racetrack", "c-maddpg"): "racetrack_c-maddpg",
    ("racetrack", "maddpg"): "racetrack_maddpg",
    ("racetrack", "mappo-l"): "racetrack_mappo-l_16m",
    ("racetrack", "macpo"): "racetrack_macpo_16m",
}


def _read_json(path: str):
    with open(path) as f:
        return json.load(f)


def _columns(rows: list[dict], fields) -> dict[str, np.ndarray]:
    return {k: np.asarray([float(r[k]) for r in rows], np.float64) for k in fields}


def _binned_episodes(path: str) -> dict[str, np.ndarray]:
    """``episodes_binned.csv`` as pseudo-episodes: one per (seed, bin), at the bin's centre, weighted."""
    from jaxsmarl.metrics import record_fields

    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        raise ValueError(f"{path} has no rows")
    fields = record_fields(k[len("mean_"):] for k in rows[0] if k.startswith("mean_"))
    cols = {k: np.asarray([float(r[f"mean_{k}"]) for r in rows], np.float64) for k in fields}
    seed = np.asarray([int(r["seed"]) for r in rows], np.float64)
    lo = np.asarray([float(r["step_from"]) for r in rows])
    hi = np.asarray([float(r["step_to"]) for r in rows])
    order = np.lexsort((lo, seed))
    out = {k: v[order] for k, v in cols.items()}
    out.update(seed=seed[order], episode=np.arange(len(rows), dtype=np.float64),
               end_step=((lo + hi) / 2)[order], weight=np.asarray([float(r["episodes"]) for r in rows])[order])
    return out


def load_record(record_dir: str) -> dict | None:
    """A record folder as a run for :mod:`train.report` / :mod:`train.figures`; None without a summary.json.

    ``episodes`` is None when the folder holds neither episode file (the tables still work, the curve is
    omitted)."""
    from jaxsmarl.metrics import ID_FIELDS, record_fields

    summary_path = os.path.join(record_dir, "summary.json")
    if not os.path.exists(summary_path):
        return None
    summary = _read_json(summary_path)
    cfg_path = os.path.join(record_dir, "config.json")
    config = _read_json(cfg_path) if os.path.exists(cfg_path) else summary["config"]
    s = summary["summary"]
    final = {k: s[k]["last_per_seed"] for k in record_fields(s) if isinstance(s.get(k), dict)}
    raw, binned = os.path.join(record_dir, "episodes.csv"), os.path.join(record_dir, "episodes_binned.csv")
    if os.path.exists(raw):
        with open(raw, newline="") as f:
            rows = list(csv.DictReader(f))
        episodes = _columns(rows, ID_FIELDS + (record_fields(rows[0]) if rows else ()))
    elif os.path.exists(binned):
        episodes = _binned_episodes(binned)
    else:
        episodes = None
    return {"dir": record_dir, "config": config, "summary": summary, "episodes": episodes, "final": final}


def load_records(root: str, table: dict[tuple[str, str], str] | None = None) -> dict[str, dict[str, dict]]:
    """``{scenario: {algo: run}}`` of the record folders of ``table`` (default :data:`RECORDS`) found in ``root``,
    in the study's scenario order."""
    table = RECORDS if table is None else table
    out: dict[str, dict[str, dict]] = {}
    for (scenario, algo), name in table.items():
        run = load_record(os.path.join(root, name))
        if run is not None:
            out.setdefault(scenario, {})[algo] = run
    return out


def missing(root: str, table: dict[tuple[str, str], str] | None = None) -> dict[str, str]:
    """``{"<scenario>_<algo>": reason}`` for every scenario x algorithm of the study without a record."""
    table = RECORDS if table is None else table
    out = {}
    for scenario, algos in STUDY.items():
        for algo in algos:
            name = table.get((scenario, algo))
            if name is None or not os.path.exists(os.path.join(root, name, "summary.json")):
                out[f"{scenario}_{algo}"] = "no committed training record"
    return out
