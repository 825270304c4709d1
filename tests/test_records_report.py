"""RESULTS.md and curves from committed training records (``python -m train.report --from ... --out ...``): it
runs on a small fixture, every figure it embeds exists, its numbers are the records' per-seed values, and the
curves drawn from binned records equal those drawn from the raw episodes."""

import csv
import json
import os
import re
import shutil
import sys

import numpy as np
import pytest

pytest.importorskip("matplotlib")

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
from bin_episodes import bin_episodes  # noqa: E402
from jaxsmarl import stats  # noqa: E402
from train import figures, records, report  # noqa: E402

ROOT = os.path.join(os.path.dirname(__file__), "..")
TRAINING = os.path.join(ROOT, "benchmarks", "results", "training")
DOCS_RESULTS = os.path.join(ROOT, "docs", "results")


def _embedded(text):
    return re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)


def _binned_copy(src, dst, bin_steps):
    """A record folder like ``src`` whose episodes are only in episodes_binned.csv."""
    os.makedirs(dst)
    for f in ("config.json", "summary.json", "eval.csv"):
        shutil.copy(os.path.join(src, f), dst)
    header, rows = bin_episodes(os.path.join(src, "episodes.csv"), bin_steps)
    with open(os.path.join(dst, "episodes_binned.csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)


def test_report_from_a_small_fixture(tmp_path, capsys):
    rec = tmp_path / "records"
    rec.mkdir()
    shutil.copytree(os.path.join(TRAINING, "intersection_s-maddpg"), rec / "inter_s")  # raw episodes.csv
    _binned_copy(os.path.join(TRAINING, "intersection_cs-maddpg"), str(rec / "inter_cs"), 1000)
    shutil.copytree(os.path.join(TRAINING, "merge_csq"), rec / "m", ignore=shutil.ignore_patterns("episodes*"))
    out = tmp_path / "out"
    (out / "figures").mkdir(parents=True)
    (out / "figures" / "intersection_s-maddpg.gif").write_bytes(b"GIF89a")
    with open(out / "figures" / "gifs.json", "w") as f:
        json.dump({"gifs": {"intersection_s-maddpg": "1 seed x 20,000 steps"},
                   "no_gif": {"merge_csq": "not trained for this test"}}, f)
    table = {("merge", "csq"): "m", ("intersection", "cs-maddpg"): "inter_cs", ("intersection", "s-maddpg"): "inter_s"}
    res = report.write_records_report(str(rec), str(out), table)
    text = open(res["report"]).read()

    embedded = _embedded(text)
    assert "figures/intersection_curves.png" in embedded and "figures/intersection_s-maddpg.gif" in embedded
    for path in embedded:
        assert os.path.exists(out / path), path
    assert not os.path.exists(out / "figures" / "merge_curves.png")  # no episodes: no curve, and it says so
    assert "No training curve for CSQ: the record holds no episodes." in text
    assert "No GIF for CSQ (not trained for this test)" in text and "No GIF for CS-MADDPG" in text
    assert "- S-MADDPG (Bi-AC): 1 seed x 20,000 steps" in text
    assert "Not in this study: SQ (Bi-AC: CSQ, d=100) (no committed training record)" in text
    # every link points into the repository: the figures written here, or docs pages seen from docs/results/
    for link in re.findall(r"\]\(([^)#]+)", text):
        if link.startswith("figures/"):
            assert os.path.exists(out / link), link
        elif not link.startswith("http"):
            root = os.path.realpath(ROOT)
            target = os.path.normpath(os.path.join(root, "docs", "results", link))
            assert target.startswith(root + os.sep) and os.path.exists(target), link
    assert "§" not in text  # no section citations of documents users do not have
    assert re.search(r"on \d{4}-\d\d-\d\d", text) is None  # no date: regenerating changes nothing

    # the table's total return is the IQM [95% CI] of summary.json's per-seed last-10% means
    for name, algo in (("m", "CSQ"), ("inter_cs", "CS-MADDPG")):
        per_seed = json.load(open(rec / name / "summary.json"))["summary"]["total_return"]["last_per_seed"]
        p, lo, hi = stats.iqm_ci(per_seed)
        row = next(line for line in text.splitlines() if line.startswith(f"| {algo} | 8 x "))
        assert f"| {p:.1f} [{lo:.1f}, {hi:.1f}] |" in row

    assert report.main(["--from", str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    assert report.main(["--from", str(rec)]) == 2
    assert "error" in capsys.readouterr().err


def test_binned_records_draw_the_same_curve_as_the_raw_episodes(tmp_path):
    src = os.path.join(TRAINING, "intersection_cs-maddpg")
    _binned_copy(src, str(tmp_path / "b"), 500)
    raw, binned = records.load_record(src), records.load_record(str(tmp_path / "b"))
    assert binned["episodes"]["weight"].sum() == len(raw["episodes"]["seed"])
    for field in ("total_return", "crash", "leader_arrived"):
        curves = [figures.binned_curve(figures.per_seed_series(r, field), 20000, 20, reps=200) for r in (raw, binned)]
        for a, b in zip(*curves):
            np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5)  # bins of 1000 steps hold whole record bins


def test_committed_results_embed_only_files_that_exist_and_fit():
    path = os.path.join(DOCS_RESULTS, "RESULTS.md")
    assert os.path.exists(path), "docs/results/RESULTS.md is committed; regenerate it with python -m train.report"
    embedded = _embedded(open(path).read())
    assert any(p.endswith(".png") for p in embedded)
    for p in embedded:
        full = os.path.join(DOCS_RESULTS, p)
        assert os.path.exists(full), p
        limit = 300 * 1024 if p.endswith(".png") else 2 * 1024 * 1024
        assert os.path.getsize(full) < limit, (p, os.path.getsize(full))
