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
from train.restore import restore_run
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
    # One separate run, of the second configuration (not the first slice of the sweep's batched program): each
    # separate run compiles its own program; test_sweep_of_two_learning_rates_equals_four_separate_runs (slow)
    # compares every configuration.
    c, v = 1, ENV_VALUES[1]
    alone = str(tmp_path / f"alone{c}")
    assert cli.main(small_args(small) + ["--out", alone, "--set", f"env.collision_reward={v}"]) == 0
    assert json.load(open(os.path.join(alone, "config.json")))["env"] == {"collision_reward": v}
    assert json.load(open(os.path.join(folders[c], "config.json"))) == json.load(
        open(os.path.join(alone, "config.json")))
    assert_same_run(folders[c], alone, v)
    alone_state = restore_run(alone)[2]
    state, meta = sweep_state(out, alone_state, len(ENV_VALUES))
    assert meta["env_steps"] == 100
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(alone_state)):
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


@pytest.mark.slow  # a sweep and a run compiled under x64: minutes here; the dtype test below stays in the default
@pytest.mark.parametrize("key,values", [
    # values that float32 cannot hold: float32 inputs into the float64 simulator would differ
    ("env.collision_reward", [-1.1, -2.3]),
    # a learning rate meets float32 network parameters: a float64 (not weakly typed) input would differ
    ("lr", [1e-3, 3.3e-3])])
def test_sweep_equals_the_separate_run_under_x64(x64, tmp_path, key, values):
    small = dict(SMALL, eval_episodes=0)
    out, alone = str(tmp_path / "sweep"), str(tmp_path / "alone")
    assert cli.main(small_args(small) + ["--out", out, "--sweep", f"{key}={json.dumps(values)}"]) == 0
    assert cli.main(small_args(small) + ["--out", alone, "--set", f"{key}={values[1]}"]) == 0
    folder = os.path.join(out, json.load(open(os.path.join(out, "sweep.json")))["configurations"][1]["folder"])
    assert_same_run(folder, alone, (key, values[1]))
    want = restore_run(alone)[2]
    assert any(np.asarray(x).dtype == np.float64 for x in jax.tree.leaves(want))  # the program ran in float64
    state, meta = sweep_state(out, want, len(values))
    assert meta["env_steps"] == 100
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(want)):
        assert a.dtype == np.asarray(b).dtype
        np.testing.assert_array_equal(a[1], np.asarray(b))  # both seeds, the whole training state


def test_sweep_values_have_the_dtype_of_a_separate_runs_values(x64):
    from train.sweep import sweep_values
    from train.trainer import make_env

    cfg = load_config("merge", "csq", {})
    params = make_env("merge")[2]
    keys = ["lr", "cost_threshold", "env.collision_reward", "env.init_speed", "env.acceleration_range"]
    grid = sweep_configs(cfg, parse_sweep(["lr=[1e-3,3e-3]", "cost_threshold=[2,[3,4]]", "env.collision_reward=[-1,-2]",
                                           "env.init_speed=[[20,25],[22,22]]",
                                           "env.acceleration_range=[[-4,4],[-5,5]]"]))
    values = sweep_values(grid, keys, params)
    assert len(grid) == 32
    # numbers stay Python floats (weakly typed default floats in the program, as a separate run's constants)
    assert values["lr"][:2] == [1e-3, 1e-3] and values["cost_threshold"][:2] == [[2.0, 2.0], [2.0, 2.0]]
    assert all(type(x) is float for x in values["env.collision_reward"])
    assert values["env.acceleration_range"][:2] == [[-4.0, 4.0], [-5.0, 5.0]]
    # arrays get the default float dtype (float64 here, float32 without x64)
    assert values["env.init_speed"].dtype == np.float64 and values["env.init_speed"].shape == (32, 2)
    with jax.enable_x64(False):
        assert sweep_values(grid, keys, params)["env.init_speed"].dtype == np.float32


def test_a_finished_sweep_refuses_a_smaller_budget(env_sweep, tmp_path, capsys):
    import shutil

    full, _ = env_sweep
    out = str(tmp_path / "sweep")
    shutil.copytree(full, out)
    before = {name: open(os.path.join(out, name)).read() for name in
              ("sweep.json", os.path.join("configs", "env.collision_reward=-1", "config.json"))}
    assert cli.main(["--quiet", "--out", out, "--resume", "--steps", "75"]) == 2
    assert "--resume --steps 75: the run already has 100 env steps per seed" in capsys.readouterr().err
    for name, text in before.items():  # a refused resume leaves the sweep as it was
        assert open(os.path.join(out, name)).read() == text, name


@pytest.mark.slow  # two more sweeps (the longer one from the start, and the continuation): about a minute
def test_a_finished_sweep_trained_further_equals_the_longer_sweep(env_sweep, tmp_path):
    import shutil

    full, small = env_sweep
    out, longer = str(tmp_path / "further"), str(tmp_path / "longer")
    shutil.copytree(full, out)
    assert cli.main(["--quiet", "--out", out, "--resume", "--steps", "150"]) == 0
    sweep = f"env.collision_reward={json.dumps(ENV_VALUES)}"
    assert cli.main(small_args(dict(small, total_steps=150)) + ["--out", longer, "--sweep", sweep]) == 0
    saved = json.load(open(os.path.join(out, "sweep.json")))
    assert saved["finished"] and saved["base"]["total_steps"] == 150
    for c in saved["configurations"]:
        assert_same_run(os.path.join(out, c["folder"]), os.path.join(longer, c["folder"]), c["values"])
        assert json.load(open(os.path.join(out, c["folder"], "config.json")))["total_steps"] == 150
    like = state_template(dict(small, total_steps=150))
    got, meta = sweep_state(out, like, len(ENV_VALUES))
    want, _ = sweep_state(longer, like, len(ENV_VALUES))
    assert meta["env_steps"] == 150
    for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
        np.testing.assert_array_equal(a, b)


def state_template(small: dict):
    """Zeros shaped as the training state of one configuration's seeds (a restore template; nothing is compiled)."""
    from train.build import make_train
    from train.trainer import seed_keys

    cfg = load_config(small["scenario"], small["algo"], {k: v for k, v in small.items() if k not in ("scenario",
                                                                                                      "algo")})
    shapes = jax.eval_shape(jax.vmap(make_train(cfg).init), seed_keys(cfg))
    return jax.tree.map(lambda x: np.zeros(x.shape, x.dtype), shapes)
