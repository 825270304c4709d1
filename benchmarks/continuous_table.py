"""The continuous algorithms side by side: a markdown table from the committed run summaries.

    python benchmarks/continuous_table.py [RESULTS_DIR]   # default benchmarks/results/training

For every ``<scenario>_<algo>[_suffix]/summary.json`` of intersection and racetrack it prints one row: the last 10%
of each seed's training episodes and the greedy evaluation, as mean [95% bootstrap interval] across seeds (the
intervals ``python -m train`` wrote into summary.json), next to the authors' recorded runs (mean +- population std
over their seeds, ``train.reference_results.authors_summary``). The comparison table of docs/results.md is this
script's output.
"""

from __future__ import annotations

import glob
import json
import os
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from train.reference_results import authors_summary  # noqa: E402

ORDER = ["cs-maddpg", "s-maddpg", "c-maddpg", "maddpg", "mappo-l", "macpo"]
SCENARIOS = ["intersection", "racetrack"]


def _ci(entry, digits: int = 1) -> str:
    m, lo, hi = entry
    return f"{m:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _authors(scenario: str, algo: str, field: str, digits: int) -> str:
    summary = authors_summary(scenario, algo, field)
    if summary is None:
        return "n/r"
    mean, std, n = summary
    return f"{mean:.{digits}f} ± {std:.{digits}f}" if n > 1 else f"{mean:.{digits}f}"


def rows(results_dir: str) -> list[tuple[str, str, str, dict]]:
    """``[(scenario, algo, folder, summary)]`` for every continuous run folder, in table order."""
    found = []
    for path in glob.glob(os.path.join(results_dir, "*", "summary.json")):
        folder = os.path.basename(os.path.dirname(path))
        with open(path) as f:
            run = json.load(f)
        cfg = run["config"]
        if cfg["scenario"] in SCENARIOS and cfg["algo"] in ORDER and run.get("finished"):
            found.append((cfg["scenario"], cfg["algo"], folder, run))
    found.sort(key=lambda r: (SCENARIOS.index(r[0]), ORDER.index(r[1]), r[3]["config"]["total_steps"], r[2]))
    return found


def table(results_dir: str) -> str:
    head = ("| scenario | algorithm (folder) | seeds x steps | total return | leader / follower return | "
            "episode cost L / F | crash | arrival L / F or distance L | greedy total | greedy crash | "
            "authors' total | authors' crash |")
    lines = [head, "|" + "|".join(["---"] * (head.count("|") - 1)) + "|"]
    for scenario, algo, folder, run in rows(results_dir):
        s, e, cfg = run["summary"], run.get("eval", {}), run["config"]
        last = lambda k: s[k]["last"]  # noqa: E731
        if scenario == "intersection":
            extra = f"arrived {last('leader_arrived')[0]:.2f} / {last('follower_arrived')[0]:.2f}"
        else:
            extra = f"{last('leader_distance')[0]:.0f} m"
        greedy = _ci(e["total_return"]["mean_ci"]) if "total_return" in e else "-"
        greedy_crash = f"{e['crash']['mean_ci'][0]:.2f}" if "crash" in e else "-"
        lines.append(
            f"| {scenario} | {algo} ({folder}) | {cfg['num_seeds']} x {cfg['total_steps']:,} | "
            f"{_ci(last('total_return'))} | {last('leader_return')[0]:.1f} / {last('follower_return')[0]:.1f} | "
            f"{last('leader_cost')[0]:.2f} / {last('follower_cost')[0]:.2f} | {_ci(last('crash'), 2)} | {extra} | "
            f"{greedy} | {greedy_crash} | {_authors(scenario, algo, 'total_return', 1)} | "
            f"{_authors(scenario, algo, 'crash', 2)} |")
    return "\n".join(lines)


def main(argv=None) -> int:
    args = sys.argv[1:] if argv is None else argv
    results_dir = args[0] if args else os.path.join(ROOT, "benchmarks", "results", "training")
    if not os.path.isdir(results_dir):
        print(f"error: {results_dir} is not a folder of run results", file=sys.stderr)
        return 2
    print(table(results_dir))
    return 0


if __name__ == "__main__":
    sys.exit(main())
