"""Per-seed means of a run's episodes in bins of environment steps: a small stand-in for a large episodes.csv.

    python benchmarks/bin_episodes.py RUN_DIR [--bin 10000] [--src episodes.csv(.gz)]

Writes ``RUN_DIR/episodes_binned.csv``: one row per (seed, bin of ``end_step``) with the number of episodes that
ended in the bin and the mean of every numeric per-episode field (returns, costs, crash, arrivals, length, ...).
Used for runs whose raw per-episode file is too large to keep in the repository (tens of MB).
"""

from __future__ import annotations

import argparse
import collections
import csv
import gzip
import os

SKIP = ("seed", "episode", "env", "end_step")


def bin_episodes(src: str, bin_steps: int) -> tuple[list[str], list[list]]:
    """``(header, rows)`` of the binned table of the per-episode CSV ``src`` (plain or gzipped)."""
    if bin_steps <= 0:
        raise ValueError(f"--bin must be a positive number of environment steps, got {bin_steps}")
    opener = gzip.open if src.endswith(".gz") else open
    sums: dict = collections.defaultdict(lambda: collections.defaultdict(float))
    count: collections.Counter = collections.Counter()
    with opener(src, "rt", newline="") as f:
        reader = csv.DictReader(f)
        fields = [k for k in reader.fieldnames or () if k not in SKIP]
        if not {"seed", "end_step"} <= set(reader.fieldnames or ()):
            raise ValueError(f"{src} is not an episodes.csv: it needs the columns seed and end_step")
        for r in reader:
            key = (int(r["seed"]), (int(r["end_step"]) - 1) // bin_steps)
            count[key] += 1
            for k in fields:
                sums[key][k] += float(r[k])
    header = ["seed", "step_from", "step_to", "episodes"] + [f"mean_{k}" for k in fields]
    rows = [[s, b * bin_steps, (b + 1) * bin_steps, count[(s, b)]] +
            [f"{sums[(s, b)][k] / count[(s, b)]:.6g}" for k in fields] for s, b in sorted(count)]
    return header, rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir")
    p.add_argument("--bin", type=int, default=10000, help="environment steps per bin (default 10000)")
    p.add_argument("--src", default=None, help="per-episode CSV (default RUN_DIR/episodes.csv)")
    a = p.parse_args(argv)
    src = a.src or os.path.join(a.run_dir, "episodes.csv")
    header, rows = bin_episodes(src, a.bin)
    out = os.path.join(a.run_dir, "episodes_binned.csv")
    with open(out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    print(f"wrote {out}: {len(rows)} rows from {sum(r[3] for r in rows)} episodes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
