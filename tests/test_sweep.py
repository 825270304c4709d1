"""Sweeps in one program (train/sweep.py): a sweep equals the separate runs of its configurations, seed for seed;
keys that fix shapes or structure are refused."""

import json
import os

import jax
import numpy as np
import pytest

import train.__main__ as cli
import train.run
from train.config import load_config
from train.sweep import config_name, parse_sweep, sweep_configs, sweepable_keys

SMALL = dict(scenario="merge", algo="csq", num_seeds=2, total_steps=100, chunk_steps=50, checkpoint_every=50,
             warmup=32, batch_size=16, buffer_size=100, hidden_sizes=[16, 16], eval_episodes=1)
LRS = [1e-3, 3e-3]


@pytest.mark.parametrize("eval_episodes", [0, pytest.param(1, marks=pytest.mark.slow)])
def test_sweep_of_two_learning_rates_equals_four_separate_runs(tmp_path, eval_episodes):
    small = dict(SMALL, eval_episodes=eval_episodes)  # the greedy evaluation compiles a third program: slow
    out = str(tmp_path / "sweep")
    args = ["--quiet", "--out", out, "--sweep", f"lr={json.dumps(LRS)}"]
    for k, v in small.items():
        args += ["--scenario", v] if k == "scenario" else ["--algo", v] if k == "algo" else \
            ["--set", f"{k}={json.dumps(v)}"]
    assert cli.main(args) == 0
    sweep = json.load(open(os.path.join(out, "sweep.json")))
    assert [c["values"] for c in sweep["configurations"]] == [{"lr": lr} for lr in LRS]
    assert os.path.exists(os.path.join(out, "figures", "curves.png"))
    from jaxsmarl.checkpoints import Checkpointer

    for c, lr in enumerate(LRS):
        cfg = load_config("merge", "csq", {**{k: v for k, v in small.items() if k not in ("scenario", "algo")},
                                           "lr": lr})
        alone = train.run.run(cfg, str(tmp_path / f"alone{c}"), verbose=False)
        folder = os.path.join(out, sweep["configurations"][c]["folder"])
        assert json.load(open(os.path.join(folder, "config.json"))) == cfg
        for name in ("episodes.csv", "learner.csv") + (("eval.csv",) if eval_episodes else ()):
            with open(os.path.join(folder, name)) as a, open(tmp_path / f"alone{c}" / name) as b:
                got, want = a.read(), b.read()
            assert got == want and len(want.splitlines()) > 1, (lr, name)
        with Checkpointer(os.path.join(out, "checkpoints")) as ck:
            template = jax.tree.map(lambda x: np.stack([np.asarray(x)] * len(LRS)), alone["state"])
            state, meta = ck.restore(None, template)
        assert meta["env_steps"] == 100
        for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(alone["state"])):
            np.testing.assert_array_equal(a[c], np.asarray(b))  # both seeds, the whole training state


def test_shape_changing_keys_are_refused():
    cfg = load_config("merge", "csq", {})
    with pytest.raises(ValueError, match=r"cannot sweep 'batch_size', 'hidden_sizes'.*Sweepable keys of csq: lr, "):
        sweep_configs(cfg, parse_sweep(["batch_size=[16,32]", "hidden_sizes=[[8],[16]]", "lr=[1e-3,1e-4]"]))
    with pytest.raises(ValueError, match="at least two values"):
        parse_sweep(["lr=[1e-3]"])
    with pytest.raises(ValueError, match="JSON list"):
        parse_sweep(["lr=fast"])
    with pytest.raises(ValueError, match="must lie in"):  # every configuration is validated
        sweep_configs(cfg, parse_sweep(["gamma=[0.9,1.5]"]))
    assert "cost_threshold" in sweepable_keys("csq") and "num_envs" not in sweepable_keys("csq")
    grid = sweep_configs(cfg, parse_sweep(["lr=[1e-3,1e-4]", "cost_threshold=[2,[3,4]]"]))
    assert [(c["lr"], c["cost_threshold"]) for c in grid] == [(1e-3, [2.0, 2.0]), (1e-3, [3.0, 4.0]),
                                                               (1e-4, [2.0, 2.0]), (1e-4, [3.0, 4.0])]
    assert config_name(grid[1], ["lr", "cost_threshold"]) == "lr=0.001,cost_threshold=3_4"


def test_keys_the_program_reads_as_numbers_are_refused():
    # MADDPG's multiplier bounds are checked in Python when its agent is built: not sweepable, said before compiling
    from train.sweep import check_traceable
    from train.trainer import make_env

    cfg = load_config("racetrack", "cs-maddpg", dict(total_steps=64, chunk_steps=64, checkpoint_every=0,
                                                      warmup=16, batch_size=8, buffer_size=64, eval_episodes=1))
    env = make_env("racetrack")
    check_traceable(cfg, env, ["lr_actor", "cost_threshold"])
    with pytest.raises(ValueError, match="cannot sweep lambda_max with cs-maddpg"):
        check_traceable(cfg, env, ["lambda_max"])
