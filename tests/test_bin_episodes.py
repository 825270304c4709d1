"""benchmarks/bin_episodes.py: per-seed bin means against a direct computation on a small episodes.csv."""

import csv
import gzip
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
from bin_episodes import bin_episodes  # noqa: E402


def _write(path, rows, gz=False):
    opener = gzip.open if gz else open
    with opener(path, "wt", newline="") as f:
        w = csv.writer(f)
        w.writerow(["seed", "episode", "env", "end_step", "total_return", "crash"])
        w.writerows(rows)


@pytest.mark.parametrize("gz", [False, True])
def test_bins_match_direct_means(tmp_path, gz):
    rng = np.random.default_rng(0)
    rows = [[s, i, 0, int(e), float(r), int(c)] for s in range(3) for i, (e, r, c) in enumerate(zip(
        np.sort(rng.integers(1, 101, 40)), rng.normal(size=40), rng.integers(0, 2, 40)))]
    src = str(tmp_path / ("episodes.csv.gz" if gz else "episodes.csv"))
    _write(src, rows, gz)
    header, out = bin_episodes(src, 25)
    assert header == ["seed", "step_from", "step_to", "episodes", "mean_total_return", "mean_crash"]
    assert sum(r[3] for r in out) == len(rows)
    for seed, lo, hi, n, ret, crash in out:
        sel = [r for r in rows if r[0] == seed and lo < r[3] <= hi]  # end_step in (lo, hi]
        assert n == len(sel) > 0
        assert float(ret) == pytest.approx(np.mean([r[4] for r in sel]), rel=1e-5, abs=1e-6)
        assert float(crash) == pytest.approx(np.mean([r[5] for r in sel]), rel=1e-5)


def test_bad_input(tmp_path):
    src = str(tmp_path / "episodes.csv")
    _write(src, [[0, 0, 0, 5, 1.0, 0]])
    with pytest.raises(ValueError, match="--bin"):
        bin_episodes(src, 0)
    other = tmp_path / "x.csv"
    other.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="seed and end_step"):
        bin_episodes(str(other), 10)
