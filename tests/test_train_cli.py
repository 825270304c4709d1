"""Configuration validation, the command line, the pure ``train(key)`` and greedy evaluation."""

import csv
import json
import os

import jax
import numpy as np
import pytest

import train.programs
import train.run
from train import __main__ as cli
from train.build import make_train
from train.config import CONFIG_DIR, DEFAULTS, HELP, load_config, validate
from train.trainer import seed_keys

# ---------------------------------------------------------------------------------------------------------
# Validation: every mistake is a ValueError naming the fix, raised before anything is compiled.


@pytest.mark.parametrize("overrides, match", [
    ({"lrr": 1e-3}, "unknown config key 'lrr' for algorithm 'csq'.*Did you mean 'lr'"),
    ({"gamma": 1.5}, r"'gamma' must lie in \[0.0, 1.0\]"),
    ({"lr": 0}, "'lr' must lie in"),
    ({"tau": 0.0}, "'tau' must lie in"),
    ({"total_steps": -5}, "'total_steps' must be an integer >= 1"),
    ({"batch_size": 2.5}, "'batch_size' must be an integer"),
    ({"eps_start": [0.1, 1.5]}, r"probabilities and must lie in \[0, 1\]"),
    ({"cost_threshold": [1, 2, 3]}, "list of two numbers"),
    ({"cost_threshold": float("inf")}, "use 100 for 'unconstrained'"),
    ({"leader_rule": "nash"}, "'leader_rule' must be one of stackelberg, authors"),
    ({"td_action_noise": "yes"}, "must be true or false"),
    ({"hidden_sizes": [64, 0]}, "positive integers"),
    ({"num_envs": 3}, "must be a multiple of num_envs"),
    ({"checkpoint_every": 1500}, "multiple of chunk_steps"),
    ({"warmup": 600000}, "training would never start"),
])
def test_invalid_values_raise_with_fix(overrides, match):
    with pytest.raises(ValueError, match=match):
        load_config("merge", "csq", overrides)


def test_continuous_scenario_with_discrete_algorithm():
    with pytest.raises(ValueError, match="continuous actions.*--scenario merge"):
        load_config("intersection", "csq")
    with pytest.raises(ValueError, match="unknown scenario 'motorway'"):
        load_config("motorway", "csq")
    with pytest.raises(ValueError, match="unknown algorithm 'dqn'"):
        load_config("merge", "dqn")


def test_unknown_key_in_config_file(tmp_path):
    p = tmp_path / "c.json"
    p.write_text(json.dumps({"total_steps": 100, "batchsize": 32}))
    with pytest.raises(ValueError,
                       match="unknown config key 'batchsize' for algorithm 'csq' in .*c.json.*'batch_size'"):
        load_config("merge", "csq", config_file=str(p))
    p.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_config("merge", "csq", config_file=str(p))


def test_cli_rejects_bad_config_before_compiling(monkeypatch, capsys):
    def boom(*a, **k):
        raise AssertionError("compiled despite an invalid configuration")

    monkeypatch.setattr(train.run, "run", boom)
    monkeypatch.setattr(train.programs, "make_train", boom)
    assert cli.main(["--set", "gamma=2", "--out", "unused"]) == 2
    assert "'gamma' must lie in" in capsys.readouterr().err
    assert cli.main(["--scenario", "racetrack", "--algo", "sq"]) == 2
    assert "continuous actions" in capsys.readouterr().err
    assert cli.main(["--set", "lr"]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err


def test_shipped_configs_are_the_authors_values():
    files = sorted(f for f in os.listdir(CONFIG_DIR) if f.endswith(".json"))
    assert {"merge_csq.json", "merge_sq.json", "roundabout_csq.json", "roundabout_sq.json"} <= set(files)
    from train.config import ALGOS, SCENARIOS

    for f in files:  # every shipped file names a scenario and a registered algorithm that fit, and loads cleanly
        scenario, algo = f[:-len(".json")].split("_", 1)
        assert scenario in SCENARIOS and algo in ALGOS, f
        assert load_config(scenario, algo)["algo"] == algo
    m = load_config("merge", "csq")
    assert (m["total_steps"], m["batch_size"], m["lr"], m["gamma"], m["tau"], m["target_update_every"],
            m["warmup"], m["cost_threshold"], m["eps_start"], m["eps_min"], m["eps_decay"]) == (
        20000, 64, 1e-3, 0.95, 0.01, 10, 512, [5.0, 5.0], [0.1, 0.1], [0.0, 0.0], 5e-6)
    sq = load_config("merge", "sq")
    assert sq["cost_threshold"] == [100.0, 100.0] and sq["eps_min"] == [0.05, 0.05]
    r = load_config("roundabout", "csq")
    assert r["total_steps"] == 10000 and r["cost_threshold"] == [5.0, 5.0]
    assert validate(m) == m  # idempotent


def test_help_explains_every_option_and_key(capsys):
    with pytest.raises(SystemExit):
        cli.parse_args(["--help"])
    text = capsys.readouterr().out
    for opt in ("--scenario", "--algo", "--seeds", "--steps", "--out", "--resume", "--set", "--eval-only",
                "--num-envs", "--checkpoint-every", "--config"):
        assert opt in text
    for k in DEFAULTS:
        assert k in text and HELP[k][:20] in text


def test_print_config_applies_options(capsys):
    assert cli.main(["--scenario", "roundabout", "--algo", "sq", "--seeds", "3", "--steps", "4000",
                     "--set", "leader_rule=authors", "--set", "cost_threshold=[2, 3]", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)
    assert (cfg["scenario"], cfg["algo"], cfg["num_seeds"], cfg["total_steps"], cfg["leader_rule"],
            cfg["cost_threshold"]) == ("roundabout", "sq", 3, 4000, "authors", [2.0, 3.0])


# ---------------------------------------------------------------------------------------------------------
# End to end on the real merge scenario (small budgets).


SMALL = ["--steps", "400", "--seeds", "2", "--num-envs", "2", "--chunk-steps", "200", "--checkpoint-every", "200",
         "--set", "warmup=64", "--set", "batch_size=16", "--eval-episodes", "2"]


def test_cli_run_writes_metrics_and_evaluates(tmp_path, capsys):
    out = str(tmp_path / "run")
    assert cli.main(SMALL + ["--out", out]) == 0
    printed = capsys.readouterr().out
    assert "merge/csq x2" in printed and "steps/s" in printed and "greedy evaluation" in printed
    assert f"run folder: {out}" in printed and f"python -m train.render --checkpoint {out}" in printed
    assert sorted(f for f in os.listdir(out) if f != ".lock") == ["checkpoints", "config.json", "episodes.csv",
                                                                  "eval.csv", "learner.csv", "summary.json"]
    with open(os.path.join(out, "episodes.csv")) as f:
        rows = list(csv.DictReader(f))
    assert {r["seed"] for r in rows} == {"0", "1"} and {r["env"] for r in rows} == {"0", "1"}
    for r in rows:
        assert float(r["total_return"]) == pytest.approx(float(r["leader_return"]) + float(r["follower_return"]))
        assert 1 <= int(r["length"]) <= 20 and int(r["end_step"]) <= 400
        assert r["crash"] in ("0", "1")
    summary = json.load(open(os.path.join(out, "summary.json")))
    assert summary["finished"] and summary["timing"]["env_steps_run"] == 400
    assert len(summary["summary"]["crash"]["last_per_seed"]) == 2
    assert len(summary["eval"]["crash"]["per_seed"]) == 2
    # greedy evaluation of the saved checkpoint reproduces the post-training evaluation
    assert cli.main(["--eval-only", out, "--eval-episodes", "2"]) == 0
    ev = json.loads(capsys.readouterr().out)
    assert ev["env_steps"] == 400
    np.testing.assert_allclose(ev["total_return"]["per_seed"], summary["eval"]["total_return"]["per_seed"])

    # A run saved before a configuration key existed (here: leader_rule, at its default) still evaluates, renders
    # and resumes: the key counts as its default, which keeps the behaviour the run was trained with.
    from train.config import read_run_config
    from train.render import load_checkpoint_policy

    cfg_path = os.path.join(out, "config.json")
    saved = json.load(open(cfg_path))
    assert saved["leader_rule"] == "stackelberg"
    with open(cfg_path, "w") as f:
        json.dump({k: v for k, v in saved.items() if k != "leader_rule"}, f)
    assert read_run_config(out) == saved
    assert cli.main(["--eval-only", out, "--eval-episodes", "2"]) == 0
    np.testing.assert_allclose(json.loads(capsys.readouterr().out)["total_return"]["per_seed"],
                               summary["eval"]["total_return"]["per_seed"])
    assert load_checkpoint_policy(out, seed=1)[3]["leader_rule"] == "stackelberg"
    assert cli.main(["--out", out, "--resume", "--quiet"]) == 0  # finished: nothing to train, evaluated again
    again = json.load(open(os.path.join(out, "summary.json")))
    assert again["finished"] and again["timing"]["env_steps_run"] == 400
    with pytest.raises(ValueError, match="no config.json"):
        read_run_config(str(tmp_path))


def test_pure_train_matches_chunked_driver(tmp_path):
    """``jit(vmap(make_train(cfg).train))(keys)`` is the same computation as the host-chunked run."""
    cfg = cli.build_config(cli.parse_args(SMALL))  # 2 seeds x 2 envs x 200 iterations (run() reuses its program)
    trainer = make_train(cfg)
    state, m = jax.jit(jax.vmap(trainer.train))(seed_keys(cfg))
    assert m["episode"]["returned"].shape == (2, 200, 2)
    res = train.run.run(cfg, str(tmp_path / "r"), verbose=False)
    for x, y in zip(jax.tree.leaves(state.agent.params), jax.tree.leaves(res["state"].agent.params)):
        # compiled as one program vs. chunk by chunk: float rounding differs, the computation does not
        np.testing.assert_allclose(np.asarray(x), np.asarray(y), rtol=1e-2, atol=2e-3)
    returned = np.asarray(m["episode"]["returned"])
    assert int(returned.sum()) == len(res["log"].rows) > 0
    pure_returns = sorted(np.asarray(m["episode"]["total_return"])[returned].tolist())
    assert pure_returns == sorted(r["total_return"] for r in res["log"].rows)
