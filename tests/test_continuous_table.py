"""benchmarks/continuous_table.py: rows from run summaries, the authors' mean and std, what is left out."""

import json
import os
import statistics
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
from continuous_table import table  # noqa: E402

FIELDS = ["leader_return", "follower_return", "total_return", "leader_cost", "follower_cost", "crash",
          "leader_arrived", "follower_arrived", "leader_distance"]


def _run(path, scenario, algo, total, finished=True, steps=1000):
    summary = {f: {"last": [1.0, 0.5, 1.5]} for f in FIELDS}
    summary["total_return"] = {"last": [total, total - 1, total + 1]}
    run = {"config": {"scenario": scenario, "algo": algo, "num_seeds": 8, "total_steps": steps},
           "summary": summary, "finished": finished,
           "eval": {"total_return": {"mean_ci": [total + 5, total + 4, total + 6]}, "crash": {"mean_ci": [0.0, 0, 0]}}}
    os.makedirs(path)
    with open(os.path.join(path, "summary.json"), "w") as f:
        json.dump(run, f)


def test_table_rows(tmp_path):
    _run(tmp_path / "racetrack_macpo", "racetrack", "macpo", 62.64)
    _run(tmp_path / "racetrack_cs-maddpg", "racetrack", "cs-maddpg", 64.9, steps=500000)
    _run(tmp_path / "intersection_mappo-l", "intersection", "mappo-l", 29.3)
    _run(tmp_path / "racetrack_maddpg_part", "racetrack", "maddpg", 1.0, finished=False)  # unfinished: left out
    _run(tmp_path / "merge_csq", "merge", "csq", 58.0)  # discrete: left out
    lines = table(str(tmp_path)).splitlines()
    assert len(lines) == 2 + 3
    # intersection first, then racetrack in algorithm order (cs-maddpg before macpo)
    assert [ln.split("|")[2].strip() for ln in lines[2:]] == [
        "mappo-l (intersection_mappo-l)", "cs-maddpg (racetrack_cs-maddpg)", "macpo (racetrack_macpo)"]
    row = dict(zip([c.strip() for c in lines[0].split("|")], [c.strip() for c in lines[4].split("|")]))
    assert row["total return"] == "62.6 [61.6, 63.6]"
    assert row["greedy total"] == "67.6 [66.6, 68.6]"
    assert row["seeds x steps"] == "8 x 1,000"
    # the authors' racetrack MACPO seeds (docs/results.md): mean +- population std
    authors = [77.24, 69.00, 78.55]
    assert row["authors' total"] == f"{statistics.mean(authors):.1f} ± {statistics.pstdev(authors):.1f}"
    cs = dict(zip([c.strip() for c in lines[0].split("|")], [c.strip() for c in lines[3].split("|")]))
    assert cs["authors' total"] == "178.5 ± 31.4"  # as the authors' records give it
    assert cs["arrival L / F or distance L"] == "1 m"
    mappo = dict(zip([c.strip() for c in lines[0].split("|")], [c.strip() for c in lines[2].split("|")]))
    assert mappo["arrival L / F or distance L"] == "arrived 1.00 / 1.00"
