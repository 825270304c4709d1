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


@pytest.mark.slow  # the environment-parameter sweep test below is the default suite's sweep-equals-runs check
@pytest.mark.parametrize("eval_episodes", [0, 1])
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


# ---------------------------------------------------------------------------------------------------------------
# Environment parameters (env.<field>) and resuming a sweep

ENV_VALUES = [-1.0, -2.0]  # merge's collision_reward (default -5): crashes happen in the first 100 steps


def small_args(small: dict) -> list[str]:
    args = ["--quiet"]
    for k, v in small.items():
        args += ["--scenario", v] if k == "scenario" else ["--algo", v] if k == "algo" else \
            ["--set", f"{k}={json.dumps(v)}"]
    return args


def assert_same_run(got_dir: str, want_dir: str, what) -> None:
    for name in ("episodes.csv", "learner.csv"):
        with open(os.path.join(got_dir, name)) as a, open(os.path.join(want_dir, name)) as b:
            got, want = a.read(), b.read()
        assert got == want and len(want.splitlines()) > 1, (what, name)


def sweep_state(out: str, like, n: int):
    from jaxsmarl.checkpoints import Checkpointer

    with Checkpointer(os.path.join(out, "checkpoints")) as ck:
        template = jax.tree.map(lambda x: np.stack([np.asarray(x)] * n), like)
        return ck.restore(None, template)


@pytest.fixture(scope="module")
def env_sweep(tmp_path_factory):
    """An uninterrupted sweep of merge's collision reward (two values x two seeds) through the command line."""
    out = str(tmp_path_factory.mktemp("env_sweep") / "sweep")
    small = dict(SMALL, eval_episodes=0)
    sweep = f"env.collision_reward={json.dumps(ENV_VALUES)}"
    assert cli.main(small_args(small) + ["--out", out, "--sweep", sweep]) == 0
    return out, small


def test_sweep_of_an_environment_parameter_equals_separate_runs_with_set(env_sweep, tmp_path):
    out, small = env_sweep
    sweep = json.load(open(os.path.join(out, "sweep.json")))
    assert sweep["finished"] and [c["values"] for c in sweep["configurations"]] == [
        {"env.collision_reward": v} for v in ENV_VALUES]
    folders = [os.path.join(out, c["folder"]) for c in sweep["configurations"]]
    assert [os.path.basename(f) for f in folders] == ["env.collision_reward=-1", "env.collision_reward=-2"]
    with open(os.path.join(folders[0], "episodes.csv")) as a, open(os.path.join(folders[1], "episodes.csv")) as b:
        assert a.read() != b.read()  # the value reached the environment: the rewards differ
    states = []
    for c, v in enumerate(ENV_VALUES):
        alone = str(tmp_path / f"alone{c}")
        assert cli.main(small_args(small) + ["--out", alone, "--set", f"env.collision_reward={v}"]) == 0
        assert json.load(open(os.path.join(alone, "config.json")))["env"] == {"collision_reward": v}
        assert json.load(open(os.path.join(folders[c], "config.json"))) == json.load(
            open(os.path.join(alone, "config.json")))
        assert_same_run(folders[c], alone, v)
        from train.restore import restore_run

        states.append(restore_run(alone)[2])
    state, meta = sweep_state(out, states[0], len(ENV_VALUES))
    assert meta["env_steps"] == 100
    for c in range(len(ENV_VALUES)):
        for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(states[c])):
            np.testing.assert_array_equal(a[c], np.asarray(b))  # both seeds, the whole training state


def test_interrupted_sweep_resumes_to_the_uninterrupted_one(env_sweep, tmp_path, capsys):
    from train.sweep import parse_sweep, run_sweep

    full, small = env_sweep
    out = str(tmp_path / "sweep")
    cfg = load_config("merge", "csq", {k: v for k, v in small.items() if k not in ("scenario", "algo")})
    part = run_sweep(cfg, parse_sweep([f"env.collision_reward={json.dumps(ENV_VALUES)}"]), out, verbose=False,
                     max_chunks=1)
    assert not part["finished"] and not json.load(open(os.path.join(out, "sweep.json")))["finished"]
    # another sweep, another order of the same values, another setting: refused, the folder left as it was
    for extra, says in ((["--sweep", "env.collision_reward=[-1,-3]"], "holds another sweep"),
                        (["--sweep", "env.collision_reward=[-2,-1]"], "holds another sweep"),
                        (["--sweep", "lr=[1e-3,3e-3]"], "holds another sweep"),
                        (["--set", "lr=0.01"], "different configuration than the saved sweep")):
        assert cli.main(["--quiet", "--out", out, "--resume"] + extra) == 2
        assert says in capsys.readouterr().err, extra
    assert cli.main(["--quiet", "--out", str(tmp_path / "plain"), "--resume", "--sweep", "lr=[1e-3,3e-3]"]) == 2
    assert "holds no sweep" in capsys.readouterr().err
    # --resume alone continues the saved sweep (its base configuration and swept values)
    assert cli.main(["--quiet", "--out", out, "--resume"]) == 0
    saved = json.load(open(os.path.join(out, "sweep.json")))
    assert saved["finished"] and saved["sweep"] == {"env.collision_reward": ENV_VALUES}
    for c in saved["configurations"]:
        assert_same_run(os.path.join(out, c["folder"]), os.path.join(full, c["folder"]), c["values"])
    like = jax.tree.map(lambda x: np.asarray(x)[0], part["state"])
    resumed, meta = sweep_state(out, like, len(ENV_VALUES))
    whole, _ = sweep_state(full, like, len(ENV_VALUES))
    assert meta["env_steps"] == 100
    for a, b in zip(jax.tree.leaves(resumed), jax.tree.leaves(whole)):
        np.testing.assert_array_equal(a, b)


def test_environment_keys_that_are_not_real_numbers_are_refused():
    cfg = load_config("merge", "csq", {"env.speed_reward": 3})
    assert cfg["env"] == {"speed_reward": 3.0}
    with pytest.raises(ValueError, match=r"cannot sweep 'env.init_target_speed', 'env.nope'.*Sweepable keys of "
                                         r"csq: lr, .*environment parameters of merge: env.duration, "
                                         r".*env.collision_reward"):
        sweep_configs(cfg, parse_sweep(["env.init_target_speed=[1,2]", "env.nope=[1,2]", "lr=[1e-3,1e-4]"]))
    with pytest.raises(ValueError, match=r"env.init_speed of merge must be an array of shape \[2\]"):
        sweep_configs(cfg, parse_sweep(["env.init_speed=[20,25]"]))  # a number where the default is per vehicle
    with pytest.raises(ValueError, match="'collision_cost' is a cost and must be >= 0"):
        sweep_configs(cfg, parse_sweep(["env.collision_cost=[1,-1]"]))
    grid = sweep_configs(cfg, parse_sweep(["env.init_speed=[[20,25],[22,22]]"]))
    assert [c["env"] for c in grid] == [{"speed_reward": 3.0, "init_speed": [20.0, 25.0]},
                                        {"speed_reward": 3.0, "init_speed": [22.0, 22.0]}]
    assert config_name(grid[0], ["env.init_speed"]) == "env.init_speed=20_25"
    with pytest.raises(ValueError, match="'env' values must be finite numbers"):
        load_config("merge", "csq", {"env.speed_reward": True})
    hw = load_config("highway", "csq", {})
    with pytest.raises(ValueError, match=r"cannot sweep 'env.initial_lane_id'.*highway: env.duration, .*"
                                         r"env.reward_speed_range"):
        sweep_configs(hw, parse_sweep(["env.initial_lane_id=[0,1]"]))
    from train.trainer import config_env

    with pytest.raises(ValueError, match=r"cannot set env.normalize_reward"):
        config_env(dict(hw, env={"normalize_reward": 0.0}))
    assert config_env(dict(hw, env={"reward_speed_range": [15, 25]}))[2].reward_speed_range == (15.0, 25.0)
