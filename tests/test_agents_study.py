"""The K-agent study (train/agents_study.py): its plan, its hierarchies, its measures and its report, from
hand-made run summaries whose inter-quartile means are known in closed form; and one real run end to end (slow)."""

import json
import os

import numpy as np
import pytest

from jaxsmarl.hierarchy import validate_hierarchy
from train import agents_study, experiments


def test_hierarchies_are_valid_and_of_the_named_shape():
    for k in (2, 3, 4):
        chain = validate_hierarchy(agents_study.hierarchy("chain", k), k)
        assert [list(level) for level in chain] == [[i] for i in range(k)]
        flat = validate_hierarchy(agents_study.hierarchy("flat", k), k)
        assert [list(level) for level in flat] == [list(range(k))]
        horizontal = validate_hierarchy(agents_study.hierarchy("horizontal", k), k)
        lead = (k + 1) // 2
        assert [list(level) for level in horizontal] == [list(range(lead)), list(range(lead, k))]
    assert agents_study.hierarchy("horizontal", 4) == "0,1|2,3"
    assert agents_study.hierarchy(None, 3) is None
    with pytest.raises(ValueError, match="chain, horizontal or flat"):
        agents_study.hierarchy("diagonal", 3)


def test_plan_runs_every_method_once_per_k_and_skips_the_horizontal_copy_of_the_chain():
    items = agents_study.plan(agents=(2, 3, 4))
    names = [it["name"] for it in items]
    assert len(names) == len(set(names)) == (4 + 5 + 5) + (5 + 5)  # merge-v0 at K = 2, 3, 4; merge-cavs at 3, 4
    assert "merge-v0_K2_csq-horizontal" not in names and "merge-v0_K3_csq-horizontal" in names
    assert not any(n.startswith("merge-cavs_K2") for n in names)  # MARL_CAVs' traffic has no K = 2
    by_name = {it["name"]: it for it in items}
    assert by_name["merge-v0_K4_csq-chain"]["overrides"] == {"agents": 4, "num_seeds": 8, "hierarchy": "0|1|2|3"}
    assert by_name["merge-v0_K3_mappo-l"]["overrides"] == {"agents": 3, "num_seeds": 8}
    assert by_name["merge-cavs_K4_csq-horizontal"]["overrides"] == {"agents": 4, "num_seeds": 8,
                                                                     "hierarchy": "0,1|2,3"}
    for scenario in agents_study.SCENARIOS:  # per scenario, all methods at the smallest K first
        ks = [it["agents"] for it in items if it["scenario"] == scenario]
        assert ks == sorted(ks) and set(ks) == set(agents_study.SCENARIO_AGENTS[scenario])
    assert [it["scenario"] for it in agents_study.plan(agents=(2,))] == ["merge-v0"] * 4
    small = agents_study.plan(agents=(3,), seeds=2, steps=4096)
    assert all(it["overrides"]["num_seeds"] == 2 and it["overrides"]["total_steps"] == 4096 for it in small)
    for bad in (1, 5, 2.0):
        with pytest.raises(ValueError, match="must be 2, 3 or 4"):
            agents_study.plan(agents=(bad,))


def test_every_planned_run_resolves_to_a_valid_configuration():
    for item in agents_study.plan():
        config, reason = experiments._resolve(item)
        assert config is not None, reason
        assert config["agents"] == item["agents"] and config["scenario"] == item["scenario"]


def _summary(algo, k, per_seed_returns, crash, speed, seeds=4):
    """A finished run's summary.json with the given per-seed values (agent i's return = base + i), laid out as
    train.run writes it (summary: the last-10% statistics; eval: the greedy evaluation's)."""
    ev = {f"return_{i}": {"per_seed": [r + i for r in per_seed_returns]} for i in range(k)}
    ev.update({f"cost_{i}": {"per_seed": [5.0 * c for c in crash]} for i in range(k)})
    ev.update(crash={"per_seed": list(crash)}, speed={"per_seed": list(speed)})
    train = {f: {"last_per_seed": v["per_seed"]} for f, v in ev.items()}
    return {"finished": True, "config": {"algo": algo, "num_seeds": seeds, "total_steps": 1000},
            "summary": train, "eval": ev}


def _write(study_dir, name, summary):
    d = os.path.join(study_dir, "runs", name)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, "summary.json"), "w") as f:
        json.dump(summary, f)


def test_measures_and_report_from_known_per_seed_values(tmp_path):
    pytest.importorskip("matplotlib")
    study = str(tmp_path)
    # K = 3, chain: returns per agent (r, r+1, r+2) -> mean r + 1; IQM of 4 seeds = mean of the middle two
    _write(study, "merge-v0_K3_csq-chain", _summary("csq", 3, [1.0, 1.5, 2.0, 2.5], [0, 0, 0, 0], [20, 21, 22, 23]))
    _write(study, "merge-v0_K3_csq-flat", _summary("csq", 3, [7.0, 7.0, 7.0, 7.0], [1, 1, 1, 1], [25, 25, 25, 25]))
    unfinished = _summary("macpo", 3, [0.0] * 4, [0] * 4, [0] * 4)
    unfinished["finished"] = False
    _write(study, "merge-v0_K3_macpo", unfinished)
    runs = agents_study.collect(study)
    assert set(runs["merge-v0"][3]) == {"csq-chain", "csq-flat"}  # the unfinished run is left out
    chain = runs["merge-v0"][3]["csq-chain"]
    np.testing.assert_allclose(agents_study.measure(chain, "return", 3), [2.0, 2.5, 3.0, 3.5])
    np.testing.assert_allclose(agents_study.measure(runs["merge-v0"][3]["csq-flat"], "cost", 3), [5.0] * 4)
    np.testing.assert_allclose(agents_study.measure(chain, "return_2", 3, greedy=False), [3.0, 3.5, 4.0, 4.5])
    path = agents_study.write_report(study)
    text = open(path).read()
    assert "| 3 | csq-chain | 2.75 [" in text  # IQM of (2, 2.5, 3, 3.5) = (2.5 + 3) / 2
    assert "| 3 | csq-flat | 8.00 | 1.000 | 5.00 | 25.00 |" in text  # equal seeds: a point, no interval
    assert "csq-chain's crash rate at K = 3 is lower than csq-flat's" in text
    assert "csq-chain's return per agent at K = 3 is lower than csq-flat's" in text
    assert "macpo" not in text.split("## merge-v0")[1].split("Stackelberg")[0]
    assert "Not finished yet (left out of every table and figure): merge-v0_K2_csq-chain," in text
    assert "merge-v0_K3_macpo" in text.split("Not finished yet")[1].split("\n")[0]
    assert os.path.getsize(os.path.join(study, "figures", "merge-v0_agents.png")) > 0
    assert "(figures/merge-v0_agents.png)" in text


def test_cli_rejects_options_that_do_not_apply(capsys, tmp_path):
    out = str(tmp_path / "s")
    assert experiments.main(["--study", "agents", "--only", "merge", "--out", out]) == 2
    assert "--only and --quick do not apply" in capsys.readouterr().err
    assert experiments.main(["--study", "agents", "--agents", "5", "--out", out]) == 2
    assert "must be 2, 3 or 4" in capsys.readouterr().err
    assert experiments.main(["--agents", "3", "--out", out]) == 2
    assert "--agents applies to --study agents only" in capsys.readouterr().err
    assert not os.path.exists(out)


@pytest.mark.slow  # trains five runs
def test_study_trains_every_method_and_writes_its_report(tmp_path):
    out = str(tmp_path / "study")
    assert experiments.main(["--study", "agents", "--agents", "2", "--steps", "2048", "--seeds", "2",
                             "--set", "chunk_steps=2048", "--set", "checkpoint_every=2048",
                             "--set", "eval_episodes=2", "--out", out, "--quiet"]) == 0
    text = open(os.path.join(out, "AGENTS.md")).read()
    for method in ("csq-chain", "csq-flat", "mappo-l", "macpo"):
        assert f"| 2 | {method} |" in text
        with open(os.path.join(out, "runs", f"merge-v0_K2_{method}", "summary.json")) as f:
            s = json.load(f)
        assert s["finished"] and s["config"]["agents"] == 2 and len(s["eval"]["speed"]["per_seed"]) == 2


def test_report_from_committed_records_matches_the_committed_report(tmp_path):
    """docs/results/AGENTS.md is what python -m train.agents_study writes from benchmarks/results/agents_study;
    a folder without runs/ is refused."""
    pytest.importorskip("matplotlib")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    src = os.path.join(root, "benchmarks", "results", "agents_study")
    out = str(tmp_path / "out")
    cwd = os.getcwd()
    os.chdir(root)  # the command line the report names is relative to the repository
    try:
        assert agents_study.main(["--from", "benchmarks/results/agents_study", "--out", out]) == 0
    finally:
        os.chdir(cwd)
    made = open(os.path.join(out, "AGENTS.md")).read().replace(out, "docs/results")
    with open(os.path.join(root, "docs", "results", "AGENTS.md")) as f:
        assert made == f.read()
    assert os.path.isdir(src)
    assert agents_study.main(["--from", str(tmp_path), "--out", out]) == 2


def test_report_joins_several_folders_first_folder_wins_and_narrows_to_the_asked_runs(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    longer, base = str(tmp_path / "longer"), str(tmp_path / "base")
    _write(longer, "merge-v0_K2_csq-chain", _summary("csq", 2, [9.0] * 4, [0] * 4, [20] * 4))
    _write(base, "merge-v0_K2_csq-chain", _summary("csq", 2, [1.0] * 4, [1] * 4, [20] * 4))
    _write(base, "merge-v0_K2_macpo", _summary("macpo", 2, [3.0] * 4, [0] * 4, [20] * 4))
    _write(base, "merge-v0_K3_macpo", _summary("macpo", 3, [3.0] * 4, [0] * 4, [20] * 4))
    runs = agents_study.collect([longer, base])
    assert set(runs["merge-v0"]) == {2, 3}
    np.testing.assert_allclose(agents_study.measure(runs["merge-v0"][2]["csq-chain"], "return", 2), [9.5] * 4)
    np.testing.assert_allclose(agents_study.measure(runs["merge-v0"][2]["macpo"], "return", 2), [3.5] * 4)
    out = str(tmp_path / "out")
    assert agents_study.main(["--from", longer, "--from", base, "--out", out, "--scenario", "merge-v0",
                              "--agents", "2"]) == 0
    text = open(os.path.join(out, "AGENTS.md")).read()
    assert "| 2 | csq-chain | 9.50 |" in text and "| 2 | macpo | 3.50 |" in text
    assert "| 3 |" not in text  # K = 3 was not asked for
    missing = text.split("Not finished yet (left out of every table and figure): ")[1].split("\n")[0]
    assert missing == "merge-v0_K2_csq-flat, merge-v0_K2_mappo-l."
    assert f"--from {longer} --from {base} --out {out} --scenario merge-v0 --agents 2" in text
    # one budget only: the K = 3 baseline (1,000 steps) is left out at 2,000 steps, and so named
    _write(longer, "merge-v0_K3_csq-chain", dict(_summary("csq", 3, [2.0] * 4, [0] * 4, [20] * 4),
                                                  config={"algo": "csq", "num_seeds": 4, "total_steps": 2000}))
    assert agents_study.main(["--from", longer, "--from", base, "--out", out, "--agents", "3", "--steps", "2000"]) == 0
    text = open(os.path.join(out, "AGENTS.md")).read()
    assert "| 3 | csq-chain | 3.00 |" in text and "macpo |" not in text
    assert "No finished run of 2,000 env steps per seed (left out of every table and figure): " in text
    assert "merge-v0_K3_macpo" in text.split("No finished run")[1].split("\n")[0]
    assert agents_study.main(["--from", longer, "--out", out, "--steps", "0"]) == 2
    assert "--steps must be a positive" in capsys.readouterr().err
    with pytest.raises(ValueError, match="out_dir is required"):
        agents_study.write_report([longer, base])
    assert agents_study.main(["--from", longer, "--out", out, "--agents", "5"]) == 2
    assert "must be 2, 3 or 4" in capsys.readouterr().err


def test_equal_sample_report_from_committed_records_matches_the_committed_report(tmp_path, monkeypatch):
    """docs/results/equal_samples/AGENTS.md is what python -m train.agents_study writes from the 131,072-step CSQ
    records joined with the baselines' runs of the same budget."""
    pytest.importorskip("matplotlib")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    committed = os.path.join(root, "docs", "results", "equal_samples", "AGENTS.md")
    with open(committed) as f:
        expected = f.read()
    out = str(tmp_path / "out")
    argv = expected.split("Generated by `python -m train.agents_study ")[1].split("`")[0].split()
    argv[argv.index("--out") + 1] = out
    monkeypatch.chdir(root)  # the report's command names the record folders relative to the repository
    assert agents_study.main(argv) == 0
    made = open(os.path.join(out, "AGENTS.md")).read().replace(out, "docs/results/equal_samples")
    assert "--steps 131072" in made and made == expected
