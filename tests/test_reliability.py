"""Nothing damaged is trained on, nothing written is lost: checkpoint damage is detected and resumed past, failed
writes stop a run with earlier checkpoints intact, one run per folder, and the inputs that used to go unchecked
(a missing --config file, environment parameters outside their physical range) are refused."""

import errno
import glob
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl import buffers, metrics
from jaxsmarl.checkpoints import Checkpointer
from jaxsmarl.learner_log import LearnerLog
from tests.test_checkpoints import _leaves_equal
from train import __main__ as cli
from train.config import load_config
from train.run import run

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _state(seed: int):
    buf = buffers.init({"o": jnp.zeros((2, 64)), "a": jnp.zeros((2,), jnp.int32)}, 512)
    buf = buffers.add(buf, {"o": jax.random.normal(jax.random.PRNGKey(seed), (300, 2, 64)),
                            "a": jnp.full((300, 2), seed, jnp.int32)})
    return {"params": {"w": jax.random.normal(jax.random.PRNGKey(seed + 1), (64, 64))}, "buffer": buf,
            "key": jax.random.PRNGKey(seed + 2), "step": jnp.int32(seed)}


def _data_files(step_dir) -> list[str]:
    return sorted(glob.glob(os.path.join(str(step_dir), "state", "**", "d", "*"), recursive=True))


# Each damage to the newest checkpoint's files, as a function of its folder.
def _flip_bytes(d):
    rng = np.random.default_rng(0)
    for p in _data_files(d):  # 256 random bytes in the middle of every data file
        b = bytearray(open(p, "rb").read())
        m = len(b) // 2
        b[m:m + 256] = rng.integers(0, 256, len(b[m:m + 256]), dtype=np.uint8).tobytes()
        open(p, "wb").write(bytes(b))


def _truncate(d):
    p = max(_data_files(d), key=os.path.getsize)
    os.truncate(p, os.path.getsize(p) // 2)


def _delete_data_file(d):
    os.remove(max(_data_files(d), key=os.path.getsize))


def _delete_manifest(d):
    os.remove(os.path.join(d, "state", "manifest.ocdbt"))


def _garble_metadata(d):
    with open(os.path.join(d, "meta", "metadata"), "w") as f:
        f.write('{"chunks_done": 3, "env_')


def _garble_tree_metadata(d):
    with open(os.path.join(d, "state", "_METADATA"), "w") as f:
        f.write("not json")


def _swap_state(d):
    # a whole, readable state that is not the one this checkpoint recorded (another step's): only the digests
    # can tell
    other = os.path.join(os.path.dirname(d), "1")
    shutil.rmtree(os.path.join(d, "state"))
    shutil.copytree(os.path.join(other, "state"), os.path.join(d, "state"))


def _forge_digest_record(d):
    # valid JSON, the data untouched, but the digest record does not describe it
    p = os.path.join(d, "meta", "metadata")
    meta = json.load(open(p))
    meta["integrity"]["leaves"] = {k: "0" * 64 for k in meta["integrity"]["leaves"]}
    json.dump(meta, open(p, "w"))


DAMAGES = {"flipped bytes": _flip_bytes, "truncated data file": _truncate, "deleted data file": _delete_data_file,
           "deleted manifest": _delete_manifest, "corrupt metadata": _garble_metadata,
           "corrupt tree metadata": _garble_tree_metadata, "another step's state": _swap_state}


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_damaged_checkpoint_is_refused_and_the_previous_one_restores(tmp_path, damage):
    d = tmp_path / "ck"
    states = {1: _state(1), 2: _state(2)}
    with Checkpointer(d) as ck:
        for step, st in states.items():
            ck.save(step, st, {"s": step})
    DAMAGES[damage](str(d / "2"))
    with Checkpointer(d) as ck:
        with pytest.raises(ValueError, match=r"checkpoint 2 in .* is invalid: "):
            ck.restore(None, states[2])
        step, restored, meta = ck.restore_valid(states[2], on_skip=lambda e: None)
        assert step == 1 and meta == {"s": 1} and _leaves_equal(restored, states[1])
        assert _leaves_equal(ck.restore(1, states[2])[0], states[1])


def test_forged_digest_record_is_refused(tmp_path):
    st = _state(2)
    with Checkpointer(tmp_path / "ck") as ck:
        ck.save(2, st, {"s": 2})
    _forge_digest_record(str(tmp_path / "ck" / "2"))
    with Checkpointer(tmp_path / "ck") as ck:
        with pytest.raises(ValueError, match=r"digest of (\d+) of \1 leaves does not match"):
            ck.restore(2, st)
        with pytest.raises(ValueError, match=r"no valid checkpoint in .*ck: found 1, all invalid \(2: "):
            ck.restore_valid(st)


def test_digests_cover_every_leaf_with_its_dtype_and_shape(tmp_path):
    from jaxsmarl.checkpoints import state_digest

    st = _state(1)
    d = state_digest(jax.tree.map(np.asarray, st))
    assert len(d) == len(jax.tree.leaves(st))
    # the same bytes under another dtype or shape, and one changed bit, all have other digests
    w = np.asarray(st["params"]["w"])
    other = [state_digest({"w": w.view(np.int32)}), state_digest({"w": w.reshape(-1)}),
             state_digest({"w": np.where(np.arange(w.size).reshape(w.shape) == 7,
                                         np.nextafter(w, np.inf), w).astype(w.dtype)})]
    assert len({state_digest({"w": w})["['w']"]} | {o[next(iter(o))] for o in other}) == 4


# ---------------------------------------------------------------------------------------------------------
# Failed writes: a real write error from the kernel (RLIMIT_FSIZE: "File too large", also as root) or a refused
# folder; the checkpoints written before stay valid.


class _FileSizeLimit:
    """Writes past ``limit`` bytes into any file fail with EFBIG while active."""

    def __init__(self, limit: int):
        self.limit = limit

    def __enter__(self):
        self._old = resource.getrlimit(resource.RLIMIT_FSIZE)
        self._sig = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (self.limit, self._old[1]))

    def __exit__(self, *exc):
        resource.setrlimit(resource.RLIMIT_FSIZE, self._old)
        signal.signal(signal.SIGXFSZ, self._sig)


def test_failed_checkpoint_write_keeps_the_earlier_ones(tmp_path):
    from jaxsmarl.checkpoints import CheckpointWriteError

    d = tmp_path / "ck"
    with Checkpointer(d) as ck:
        ck.save(1, _state(1), {"s": 1})
        ck.save(2, _state(2), {"s": 2})
        with _FileSizeLimit(4096):  # the state's data file is far larger
            with pytest.raises(CheckpointWriteError,
                               match=r"could not write the checkpoint at step 3 .*intact \(1, 2\)"):
                ck.save(3, _state(3), {"s": 3})
        assert ck.all_steps() == [1, 2]
        assert not [n for n in os.listdir(d) if "tmp" in n]  # the unfinished save is cleaned away
    with Checkpointer(d) as ck:
        assert ck.all_steps() == [1, 2]
        for s in (1, 2):
            st, meta = ck.restore(s, _state(0))
            assert meta == {"s": s} and _leaves_equal(st, _state(s))
        ck.save(3, _state(3), {"s": 3})  # once there is room again, saving works
        assert ck.all_steps() == [2, 3] and _leaves_equal(ck.restore(3, _state(0))[0], _state(3))


def test_permission_denied_checkpoint_write_keeps_the_earlier_ones(tmp_path, monkeypatch):
    from orbax.checkpoint._src.path import atomicity

    from jaxsmarl.checkpoints import CheckpointWriteError

    d = tmp_path / "ck"
    with Checkpointer(d) as ck:
        ck.save(1, _state(1), {"s": 1})

        async def denied(path, *a, **k):  # the folder of the new checkpoint cannot be created
            raise PermissionError(errno.EACCES, "Permission denied", str(path))

        monkeypatch.setattr(atomicity, "_create_tmp_directory", denied)
        with pytest.raises(CheckpointWriteError, match="Permission denied.*intact \\(1\\)"):
            ck.save(2, _state(2), {"s": 2})
    monkeypatch.undo()
    with Checkpointer(d) as ck:
        assert ck.all_steps() == [1] and _leaves_equal(ck.restore(None, _state(0))[0], _state(1))


def test_metrics_files_are_never_half_written(tmp_path):
    path = tmp_path / "summary.json"
    metrics.write_json(path, {"a": 1})
    big = {"rows": list(range(100_000))}
    with _FileSizeLimit(1000):
        with pytest.raises(OSError, match="File too large"):
            metrics.write_json(path, big)
    assert json.load(open(path)) == {"a": 1} and os.listdir(tmp_path) == ["summary.json"]
    log = metrics.EpisodeLog(1, [dict({k: 0.0 for k in metrics.EPISODE_FIELDS}, seed=0, episode=e, env=0,
                                      end_step=e + 1) for e in range(3)])
    csv_path = tmp_path / "episodes.csv"
    log.write_csv(csv_path)
    before = open(csv_path).read()
    log.rows += [dict(log.rows[0], episode=e, end_step=e + 1) for e in range(3, 3000)]
    with _FileSizeLimit(len(before) + 10):
        with pytest.raises(OSError, match="File too large"):
            log.write_csv(csv_path)
    assert open(csv_path).read() == before and sorted(os.listdir(tmp_path)) == ["episodes.csv", "summary.json"]
    learner = LearnerLog([{"seed": 0, "env_steps": 100, "agent": i, "lambda": 0.5, "cost_estimate": ""}
                          for i in range(2)])
    learner_path = tmp_path / "learner.csv"
    learner.write_csv(learner_path)
    before = open(learner_path).read()
    learner.rows += [dict(learner.rows[0], env_steps=100 * k) for k in range(2, 3000)]
    with _FileSizeLimit(len(before) + 10):
        with pytest.raises(OSError, match="File too large"):
            learner.write_csv(learner_path)
    assert open(learner_path).read() == before
    assert sorted(os.listdir(tmp_path)) == ["episodes.csv", "learner.csv", "summary.json"]


# ---------------------------------------------------------------------------------------------------------
# Real merge CSQ runs: 800 steps, a checkpoint every 200 (the newest two kept), 2 seeds.


@pytest.fixture(scope="module")
def small_config():
    return load_config("merge", "csq", dict(total_steps=800, num_seeds=2, chunk_steps=200, checkpoint_every=200,
                                             warmup=100, batch_size=16, eval_episodes=0))


@pytest.fixture(scope="module")
def straight(small_config, tmp_path_factory):
    out = str(tmp_path_factory.mktemp("straight") / "run")
    res = run(small_config, out, verbose=False)
    return res, open(os.path.join(out, "episodes.csv")).read()


@pytest.mark.parametrize("damage", ["flipped bytes", "truncated data file", "deleted manifest"])
def test_resume_skips_a_damaged_checkpoint_and_stays_bit_identical(tmp_path, small_config, straight, damage,
                                                                   capsys):
    out = str(tmp_path / "b")
    run(small_config, out, verbose=False, max_chunks=3)  # "killed" after its third checkpoint (400, 600 kept)
    DAMAGES[damage](os.path.join(out, "checkpoints", "600"))
    capsys.readouterr()
    assert cli.main(["--out", out, "--resume", "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "skipped checkpoint 600 (" in said and os.path.isdir(os.path.join(out, "damaged_checkpoints", "600"))
    with Checkpointer(os.path.join(out, "checkpoints")) as ck:
        assert ck.all_steps() == [600, 800]
        resumed, meta = ck.restore(None, straight[0]["state"])
    assert meta["segments"] == 2  # continued from 400: the run's second segment wrote 600 and 800 anew
    assert _leaves_equal(straight[0]["state"], resumed)
    assert open(os.path.join(out, "episodes.csv")).read() == straight[1]


def test_no_valid_checkpoint_one_line_exit_2(tmp_path, small_config, capsys):
    from train import render

    out = str(tmp_path / "c")
    run(small_config, out, verbose=False, max_chunks=2)
    for step in ("200", "400"):
        _truncate(os.path.join(out, "checkpoints", step))
    capsys.readouterr()
    for argv, main in ((["--out", out, "--resume", "--quiet"], cli.main), (["--eval-only", out], cli.main),
                       (["--checkpoint", out, "--no-mp4"], render.main)):
        assert main(argv) == 2, argv
        time.sleep(0.3)  # orbax's reader threads report their abandoned reads shortly after the failure
        cap = capsys.readouterr()
        lines = [ln for ln in (cap.out + cap.err).splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith(f"error: no valid checkpoint in {out}/checkpoints: found 2, "
                                                       "all invalid (400: its state is unreadable"), lines
    # nothing was moved or deleted: the damaged checkpoints stay where they were
    assert sorted(os.listdir(os.path.join(out, "checkpoints"))) == ["200", "400"]


def test_eval_only_skips_a_damaged_newest_checkpoint(tmp_path, small_config, capsys):
    from train.evaluation import evaluate_checkpoint

    out = str(tmp_path / "e")
    run(small_config, out, verbose=False, max_chunks=2)
    _flip_bytes(os.path.join(out, "checkpoints", "400"))
    capsys.readouterr()
    ev = evaluate_checkpoint(out, episodes=1)
    assert ev["env_steps"] == 200
    assert "skipped checkpoint 400 of " in capsys.readouterr().err
    with pytest.raises(ValueError, match="checkpoint 400 in .* is invalid"):
        evaluate_checkpoint(out, episodes=1, step=400)


def test_failed_checkpoint_write_stops_the_run_cleanly(tmp_path, small_config, straight, monkeypatch, capsys):
    out = str(tmp_path / "w")
    real_save = Checkpointer.save
    calls = []

    def save_then_disk_full(self, step, state, meta=None):  # the disk fills up at the second checkpoint
        calls.append(step)
        if len(calls) < 2:
            return real_save(self, step, state, meta)
        with _FileSizeLimit(64 * 1024):
            return real_save(self, step, state, meta)

    monkeypatch.setattr(Checkpointer, "save", save_then_disk_full)
    capsys.readouterr()
    assert cli.main(["--out", out, "--config", _config_file(tmp_path, small_config), "--quiet"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: could not write the checkpoint at step 400 into "), err
    # the reason is the OS's (File too large) or, when tensorstore hits the limit first, its own message
    assert "intact (200)" in err[0] and err[0].endswith("the run stopped")
    monkeypatch.undo()
    with Checkpointer(os.path.join(out, "checkpoints")) as ck:
        assert ck.all_steps() == [200]
    # the lock went with the failed run, and the run resumes from what was written, exactly
    res = run(small_config, out, resume=True, verbose=False)
    assert _leaves_equal(straight[0]["state"], res["state"])
    assert open(os.path.join(out, "episodes.csv")).read() == straight[1]


def _config_file(tmp_path, cfg) -> str:
    p = tmp_path / "cfg.json"
    p.write_text(json.dumps({k: v for k, v in cfg.items() if k not in ("scenario", "algo")}))
    return str(p)


# ---------------------------------------------------------------------------------------------------------
# One run per folder.

_HOLD = ("import sys, time; from train.lock import RunLock; lock = RunLock(sys.argv[1]).acquire(); "
         "print('held', flush=True); time.sleep(120)")


def test_a_live_run_folder_is_refused_and_a_killed_one_is_not(tmp_path, small_config, capsys):
    out = str(tmp_path / "l")
    os.makedirs(out)
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, out], stdout=subprocess.PIPE, text=True, env=env,
                              cwd=ROOT)
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ValueError, match=f"{out} is being written by another running python -m train "
                                             f"\\(pid {holder.pid}\\)"):
            run(small_config, out, verbose=False, max_chunks=1)
        for argv in (["--out", out, "--quiet"], ["--out", out, "--overwrite", "--quiet"],
                     ["--out", out, "--resume", "--quiet"]):
            assert cli.main(argv) == 2
            assert "is being written by another running python -m train" in capsys.readouterr().err
        assert os.listdir(out) == [".lock"]  # nothing was touched
    finally:
        holder.kill()  # SIGKILL: no clean-up runs in the holder
        holder.wait()
    assert run(small_config, out, verbose=False, max_chunks=1)["summary"]["timing"]["segments"] == 1
    # and --overwrite of a finished run keeps working (the lock file itself survives the clearing)
    assert not run(small_config, out, overwrite=True, verbose=False, max_chunks=1)["summary"]["finished"]


# ---------------------------------------------------------------------------------------------------------
# Inputs that used to go unchecked.


def test_missing_or_unreadable_config_file(tmp_path, capsys):
    assert cli.main(["--config", str(tmp_path / "nonexistent.json"), "--print-config"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: config file {tmp_path / 'nonexistent.json'} does not exist; give the path of a JSON file " \
                  "of key: value pairs"
    assert cli.main(["--config", str(tmp_path), "--print-config"]) == 2
    assert "is a folder, not a JSON file" in capsys.readouterr().err
    bad = tmp_path / "bad.json"
    bad.write_bytes(b"\xff\xfe{\x00")
    assert cli.main(["--config", str(bad), "--print-config"]) == 2
    assert "is not valid JSON" in capsys.readouterr().err


@pytest.mark.parametrize("scenario, overrides, match", [
    ("merge", {"duration": -1.0}, r"'duration' is an episode length in seconds and must be > 0, got -1.0"),
    ("roundabout", {"duration": 0.0}, r"'duration' .* must be > 0"),
    ("merge", {"collision_cost": -5.0}, r"'collision_cost' is a cost and must be >= 0"),
    ("racetrack", {"lane_centering_cost": -4.0}, r"'lane_centering_cost' .* must be >= 0"),
    ("racetrack", {"offroad_cost": -0.5}, r"'offroad_cost' is a cost and must be >= 0"),
    ("racetrack", {"start_s": -1.0}, r"'start_s' .* must be >= 0"),
    ("intersection", {"start_noise": -1.0}, r"'start_noise' is a standard deviation .* must be >= 0"),
    ("intersection", {"start_s": [61.0, -3.0]}, r"'start_s' .* must be >= 0, got \[61.0, -3.0\]"),
    ("intersection", {"arrival_s": -5.0}, r"'arrival_s' .* must be >= 0"),
    ("roundabout", {"speed_band_low": 20.0}, r"speed_band_low \(20\) must not exceed speed_band_high \(15\)"),
    ("roundabout", {"speed_band_high": -1.0}, r"'speed_band_high' is a speed in m/s and must be >= 0"),
    ("merge", {"target_speeds": [-5.0, 0.0, 5.0]}, r"'target_speeds' is speeds in m/s and must be >= 0"),
    ("intersection", {"acceleration_range": (5.0, -5.0)},
     r"'acceleration_range' must be \(low, high\) with low < high"),
    ("racetrack", {"steering_range": (0.5, 0.5)}, r"'steering_range' must be \(low, high\) with low < high"),
    ("merge", {"obstacles": [[100.0, 14.5, 0.0, 0.0, 2.0]]}, r"obstacles rows .* length and width > 0"),
    ("merge", {"policy_frequency": 0}, r"0 < policy_frequency <= simulation_frequency"),
    ("merge", {"simulation_frequency": -15}, r"0 < policy_frequency <= simulation_frequency"),
])
def test_environment_parameters_outside_their_physical_range(scenario, overrides, match):
    import envs_jax

    with pytest.raises(ValueError, match=f"{scenario}: .*{match}"):
        envs_jax.make(scenario, **overrides)


def test_environment_parameters_at_the_edge_of_their_range_are_accepted():
    import envs_jax

    env = envs_jax.make("racetrack", lane_centering_cost=0.0, offroad_cost=0.0, collision_cost=0.0, start_s=0.0)
    assert env.default_params.lane_centering_cost == 0.0
    env = envs_jax.make("roundabout", speed_band_low=12.0, speed_band_high=12.0, duration=0.5)
    assert env.default_params.duration == 0.5


NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("task, overrides, match", [
    ("highway-v0", {"collision_cost": -1.0}, r"collision_cost is a cost and must be >= 0, got -1.0"),
    ("merge-v0", {"collision_cost": -5.0}, r"collision_cost is a cost and must be >= 0"),
    ("roundabout-v0", {"collision_cost": -0.1}, r"collision_cost is a cost and must be >= 0"),
    ("intersection-v0", {"collision_cost": -2.0}, r"collision_cost is a cost and must be >= 0"),
    ("racetrack-v0", {"lane_centering_cost": -4.0}, r"lane_centering_cost is a cost and must be >= 0"),
    ("highway-v0", {"reward_speed_range": [20.0, NAN]}, r"reward_speed_range must be \[low, high\] of finite"),
    ("merge-v0", {"reward_speed_range": [-INF, 30.0]}, r"reward_speed_range must be \[low, high\] of finite"),
    ("intersection-v0", {"reward_speed_range": [7.0, INF]}, r"reward_speed_range must be \[low, high\] of finite"),
    ("merge-v0", {"idm": {"comfort_acc_min": 1.0}}, r"idm comfort_acc_min is a deceleration .* must be < 0"),
    ("roundabout-v0", {"idm": {"distance_wanted": -1.0}}, r"idm distance_wanted is a jam distance in metres "
                                                            r"and must be >= 0, got -1.0"),
    ("intersection-v0", {"idm": {"time_wanted": -1.5}}, r"idm time_wanted is a time gap in seconds and must be >= 0"),
    ("racetrack-v0", {"idm": {"politeness": 2.0}}, r"idm politeness is a weight in \[0, 1\] and must be >= 0 and <= 1"),
    ("highway-v0", {"idm": {"acc_max": 0.0}}, r"idm acc_max is an acceleration in m/s\^2 and must be > 0"),
    ("highway-fast-v0", {"idm": {"delta": NAN}}, r"idm delta is an exponent and must be > 0, got nan"),
    ("highway-fast-v0", {"idm": {"delta_range": (4.5, 3.5)}},
     r"idm delta_range must be \(low, high\) .* 0 < low <= high"),
])
def test_traffic_task_parameters_outside_their_physical_range(task, overrides, match):
    # highway-env's tasks take costs, the reward's speed range and the IDM drivers' constants; a comfort
    # deceleration that is not negative, for one, makes every driver's desired gap non-finite (sqrt(-a_max b_min))
    import envs_jax

    with pytest.raises(ValueError, match=f"{task}: {match}"):
        envs_jax.make(task, **overrides)


def test_traffic_task_parameters_at_the_edge_of_their_range_are_accepted():
    import envs_jax

    env = envs_jax.make("racetrack-v0", collision_cost=0.0, offroad_cost=0.0, lane_centering_cost=0.0,
                        idm={"politeness": 1.0, "distance_wanted": 0.0, "time_wanted": 0.0, "lane_change_delay": 0.0})
    assert env.default_params.idm.politeness == 1.0 and env.default_params.lane_centering_cost == 0.0
    env = envs_jax.make("highway-v0", collision_cost=0.0, reward_speed_range=[30, 20],
                        idm={"delta_range": (4.0, 4.0), "politeness": 0.0})
    assert env.default_params.reward_speed_range == (30.0, 20.0) and env.default_params.collision_cost == 0.0


def test_fuzzer_counts_non_finite_steps():
    # benchmarks/fuzz_env.py's counter, on an env whose reward is NaN at every step (params set past make()'s
    # checks) and on the same env as shipped; its adversarial actions hold NaN, infinities and huge values
    import importlib.util

    import envs_jax
    from envs_jax.env import DrivingEnv

    spec = importlib.util.spec_from_file_location("fuzz_env", os.path.join(ROOT, "benchmarks", "fuzz_env.py"))
    fuzz_env = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fuzz_env)
    env = envs_jax.make("racetrack")
    a = jax.vmap(fuzz_env.adversarial_actions(env))(jax.random.split(jax.random.PRNGKey(0), 500))
    assert np.isnan(a).any() and np.isposinf(a).any() and np.isneginf(a).any() and (np.abs(a) == 1e30).any()
    assert ((np.abs(a) > 1) & np.isfinite(a)).any() and (np.abs(a) <= 1).any()
    broken = DrivingEnv(env.scenario, env.simulation_frequency, env.policy_frequency,
                        env.default_params.replace(lane_centering_reward=float("nan")))
    res = fuzz_env.fuzz(broken, 64, 8, 8, 0)
    assert res["steps"] == 64 and res["bad_steps"] == res["bad_by_output"]["reward"] >= 32
    assert res["bad_by_output"]["cost"] == res["bad_by_output"]["state"] == 0
    assert fuzz_env.fuzz(env, 64, 8, 8, 0)["bad_steps"] == 0


class _Planted:
    """An env that puts a NaN into the last float of its returned state and of its observation at every step."""

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def step(self, key, state, action, params=None):
        obs, st, reward, cost, done, info = self.env.step(key, state, action, params)
        return obs.at[-1, -1].set(jnp.nan), st.replace(y=st.y.at[-1].set(jnp.nan)), reward, cost, done, info


def test_fuzzer_counts_every_step_with_a_planted_non_finite_value():
    # a NaN in one float of the last vehicle's state and of the last agent's observation, at every step: every
    # step is counted, under those two outputs only, across segments (3 segments of 4 envs x 4 steps)
    import importlib.util

    import envs_jax

    spec = importlib.util.spec_from_file_location("fuzz_env", os.path.join(ROOT, "benchmarks", "fuzz_env.py"))
    fuzz_env = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(fuzz_env)
    res = fuzz_env.fuzz(_Planted(envs_jax.make("merge")), 48, 4, 4, 0)
    assert res["steps"] == 48 and res["complete"] and res["bad_steps"] == 48
    assert res["bad_by_output"] == {"state": 48, "observation": 48, "reward": 0, "cost": 0}
