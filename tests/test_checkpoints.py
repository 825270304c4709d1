"""Orbax checkpoints: exact round trip, atomic saves, and bit-identical resume of real training runs (off-policy
on one device; on-policy with the seeds split over two devices)."""

import json
import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl import buffers
from jaxsmarl.checkpoints import Checkpointer
from train.config import load_config
from train.run import run

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _leaves_equal(a, b) -> bool:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    return len(la) == len(lb) and all(
        np.asarray(x).dtype == np.asarray(y).dtype and np.array_equal(np.asarray(x), np.asarray(y))
        for x, y in zip(la, lb))


def _state():
    buf = buffers.init({"o": jnp.zeros((2, 8)), "a": jnp.zeros((2,), jnp.int32), "t": jnp.zeros((2,), bool)}, 16)
    buf = buffers.add(buf, {"o": jax.random.normal(jax.random.PRNGKey(1), (5, 2, 8)),
                            "a": jnp.arange(10, dtype=jnp.int32).reshape(5, 2), "t": jnp.ones((5, 2), bool)})
    return {"params": {"w": jax.random.normal(jax.random.PRNGKey(0), (3, 4))}, "buffer": buf,
            "key": jax.random.split(jax.random.PRNGKey(2), 4), "step": jnp.int32(7), "eps": jnp.float32(0.05)}


def test_round_trip_is_exact(tmp_path):
    st = _state()
    with Checkpointer(tmp_path / "ck") as ck:
        ck.save(100, st, {"chunks_done": 3, "env_steps": 100})
        restored, meta = ck.restore(None, st)
    assert meta == {"chunks_done": 3, "env_steps": 100}
    assert _leaves_equal(st, restored)
    assert jax.tree.structure(st) == jax.tree.structure(restored)


def test_keeps_newest_and_ignores_unfinished_saves(tmp_path):
    st = _state()
    d = tmp_path / "ck"
    with Checkpointer(d, max_to_keep=2) as ck:
        for step in (10, 20, 30):
            ck.save(step, st, {"s": step})
        assert ck.all_steps() == [20, 30]
    # an interrupted save leaves only a temporary folder behind; it must not count as a checkpoint
    os.makedirs(d / "40.orbax-checkpoint-tmp-1234" / "state")
    with Checkpointer(d, max_to_keep=2) as ck:
        assert ck.latest_step() == 30
        _, meta = ck.restore(None, st)
        assert meta == {"s": 30}
        assert ck.restore(20, st)[1] == {"s": 20} and ck.meta(20) == {"s": 20}
        # a step that was never saved, was dropped, or never finished: a clear error naming the saved steps
        for step in (10, 25, 40):
            with pytest.raises(ValueError, match=f"no checkpoint at step {step} .*saved steps: 20, 30"):
                ck.restore(step, st)
        with pytest.raises(ValueError, match="saved steps: 20, 30"):
            ck.meta(10)


def test_restore_missing_raises(tmp_path):
    with Checkpointer(tmp_path / "empty") as ck:
        with pytest.raises(FileNotFoundError):
            ck.restore(None, _state())


# ---------------------------------------------------------------------------------------------------------
# Resume of a real merge training run: k chunks straight == k/2 chunks, "crash", resume, k/2 chunks.


@pytest.fixture(scope="module")
def small_config():
    return load_config("merge", "csq", dict(total_steps=800, num_seeds=2, chunk_steps=200, checkpoint_every=200,
                                             warmup=100, batch_size=16, eval_episodes=0))


def test_resume_is_bit_identical(tmp_path, small_config):
    straight = run(small_config, str(tmp_path / "a"), verbose=False)
    part = run(small_config, str(tmp_path / "b"), verbose=False, max_chunks=2)
    assert not part["summary"]["finished"]
    assert not _leaves_equal(part["state"].agent.params, straight["state"].agent.params)
    resumed = run(small_config, str(tmp_path / "b"), resume=True, verbose=False)
    assert resumed["summary"]["finished"]
    # every leaf of the training state: params, Adam, targets, buffer, env states, RNG keys, counters
    assert _leaves_equal(straight["state"], resumed["state"])
    with open(tmp_path / "a" / "episodes.csv") as fa, open(tmp_path / "b" / "episodes.csv") as fb:
        assert fa.read() == fb.read()
    assert int(np.asarray(resumed["state"].iteration)[0]) == 800
    # the run's time adds up over both segments
    t_part, t_res = part["summary"]["timing"], resumed["summary"]["timing"]
    assert t_res["segments"] == 2 and straight["summary"]["timing"]["segments"] == 1
    assert t_res["train_s_total"] == pytest.approx(t_part["train_s"] + t_res["train_s"])


def test_resume_and_overwrite_guards(tmp_path, small_config):
    out = str(tmp_path / "g")
    with pytest.raises(ValueError, match="--resume"):
        run(small_config, out, resume=True, verbose=False)  # nothing to resume
    cfg = small_config
    run(cfg, out, verbose=False, max_chunks=1)
    with pytest.raises(ValueError, match="already holds a run"):
        run(cfg, out, verbose=False)
    with pytest.raises(ValueError, match="different configuration"):
        run(dict(cfg, lr=1e-4), out, resume=True, verbose=False)
    with open(os.path.join(out, "config.json")) as f:
        saved = json.load(f)
    assert saved["lr"] == cfg["lr"]
    # a run saved before a configuration key existed resumes when the key keeps its default ...
    from train.config import defaults_for

    key = next(k for k, v in cfg.items() if k in defaults_for("csq") and v == defaults_for("csq")[k]
               and k not in ("algo", "scenario", "total_steps"))
    with open(os.path.join(out, "config.json"), "w") as f:
        json.dump({k: v for k, v in saved.items() if k != key}, f)
    assert run(cfg, out, resume=True, verbose=False, max_chunks=1)["summary"]["timing"]["segments"] == 2
    # ... and not when this run sets it otherwise
    assert cfg["batch_size"] != defaults_for("csq")["batch_size"]
    with open(os.path.join(out, "config.json"), "w") as f:
        json.dump({k: v for k, v in saved.items() if k != "batch_size"}, f)
    with pytest.raises(ValueError, match="different configuration"):
        run(cfg, out, resume=True, verbose=False)


# ---------------------------------------------------------------------------------------------------------
# The same for an on-policy run (MAPPO-L) whose seeds are split over two CPU devices (train.parallel.seed_parallel).
# The device count is fixed when JAX starts, so this runs in a fresh interpreter and reports back as JSON.

_TWO_DEVICE_RESUME = textwrap.dedent("""
    import json, sys
    import jax
    jax.config.update("jax_num_cpu_devices", 2)
    import numpy as np
    from train.config import load_config
    from train.run import run

    def equal(a, b):
        la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
        return len(la) == len(lb) and all(np.asarray(x).dtype == np.asarray(y).dtype
                                          and np.array_equal(np.asarray(x), np.asarray(y)) for x, y in zip(la, lb))

    def placement(state):  # per leaf: devices holding it, and the seeds each device holds
        return sorted({(len(x.sharding.device_set), tuple(sorted(s.data.shape[0] for s in x.addressable_shards)))
                       for x in jax.tree.leaves(state)})

    tmp = sys.argv[1]
    cfg = load_config("intersection", "mappo-l", dict(
        total_steps=256, num_seeds=2, num_envs=8, rollout_length=8, num_minibatches=2, ppo_epochs=2,
        chunk_steps=64, checkpoint_every=64, eval_episodes=0))  # 4 chunks of one rollout + update each
    straight = run(cfg, tmp + "/a", verbose=False)
    part = run(cfg, tmp + "/b", verbose=False, max_chunks=2)  # same compiled program (memoised per process)
    part_differs = not equal(part["state"].agent, straight["state"].agent)
    resumed = run(cfg, tmp + "/b", resume=True, verbose=False)
    csv = [open(tmp + d + "/episodes.csv").read() for d in ("/a", "/b")]
    print(json.dumps({
        "devices": len(jax.devices()), "placement": placement((straight["state"], resumed["state"])),
        "finished": [part["summary"]["finished"], resumed["summary"]["finished"]], "part_differs": part_differs,
        "equal": equal(straight["state"], resumed["state"]), "csv_equal": csv[0] == csv[1],
        "episodes": len(straight["log"].rows), "iteration": np.asarray(resumed["state"].iteration).tolist(),
        "segments": resumed["summary"]["timing"]["segments"]}))
""")


def test_onpolicy_resume_on_two_devices_is_bit_identical(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}  # conftest pins one device
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    res = subprocess.run([sys.executable, "-c", _TWO_DEVICE_RESUME, str(tmp_path)], capture_output=True,
                         text=True, env=env, cwd=ROOT, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2
    # every leaf of both final states split over the two devices, one seed on each
    assert out["placement"] == [[2, [1, 1]]], out
    assert out["finished"] == [False, True] and out["part_differs"]
    # every leaf of the training state: actor/critics, Adam, lambda, normalisers, env states, RNG keys, counters
    assert out["equal"], out
    assert out["csv_equal"] and out["episodes"] > 0, out
    assert out["iteration"] == [32, 32] and out["segments"] == 2


# ---------------------------------------------------------------------------------------------------------
# Training a run further: --resume with a larger --steps continues exactly the run the larger budget would have
# made, and refuses where it could not (fewer steps than saved, a partial last chunk, a replay buffer that would
# change size).


@pytest.mark.slow  # long: the default suite keeps its 20-minute budget (docs/performance.md)
def test_onpolicy_run_trained_further_equals_the_longer_run(tmp_path):
    from train.__main__ import main

    cfg = load_config("intersection", "mappo-l", dict(
        total_steps=256, num_seeds=2, num_envs=8, rollout_length=8, num_minibatches=2, ppo_epochs=2,
        chunk_steps=64, checkpoint_every=64, eval_episodes=0))
    straight = run(cfg, str(tmp_path / "a"), verbose=False)
    short = run(dict(cfg, total_steps=128), str(tmp_path / "b"), verbose=False)
    assert short["summary"]["finished"] and not _leaves_equal(short["state"].agent, straight["state"].agent)
    out = str(tmp_path / "b")
    with pytest.raises(ValueError, match="already has 128 env steps"):
        run(dict(cfg, total_steps=64), out, resume=True, verbose=False)
    # through the command line: the saved configuration with only the budget changed
    assert main(["--out", out, "--resume", "--steps", "256", "--quiet"]) == 0
    with open(os.path.join(out, "config.json")) as f:
        assert json.load(f) == cfg
    with open(tmp_path / "a" / "episodes.csv") as fa, open(tmp_path / "b" / "episodes.csv") as fb:
        assert fa.read() == fb.read()
    with Checkpointer(tmp_path / "b" / "checkpoints") as ck:
        assert ck.latest_step() == 256 and ck.meta()["segments"] == 2
        resumed, _ = ck.restore(None, straight["state"])
    assert _leaves_equal(straight["state"], resumed)


@pytest.mark.slow  # long: the default suite keeps its 20-minute budget (docs/performance.md)
def test_training_further_is_refused_where_it_would_not_be_exact(tmp_path, small_config):
    # merge CSQ: 800 steps in chunks of 200; the default buffer (500000) holds min(buffer_size, total_steps)
    out = str(tmp_path / "c")
    run(dict(small_config, total_steps=400), out, verbose=False)
    with pytest.raises(ValueError, match="change shape"):
        run(small_config, out, resume=True, verbose=False)
    with open(os.path.join(out, "config.json")) as f:
        assert json.load(f)["total_steps"] == 400  # a refused resume leaves the saved run as it was
    out = str(tmp_path / "d")  # 300 steps: one chunk of 200 and a partial one of 100
    run(dict(small_config, total_steps=300, buffer_size=200), out, verbose=False)
    with pytest.raises(ValueError, match="partial chunk"):
        run(dict(small_config, buffer_size=200), out, resume=True, verbose=False)
    # with a buffer that is already full at the saved budget, an off-policy run can be trained further exactly
    cfg = dict(small_config, buffer_size=200)
    straight = run(cfg, str(tmp_path / "e"), verbose=False)
    run(dict(cfg, total_steps=400), str(tmp_path / "f"), verbose=False)
    resumed = run(cfg, str(tmp_path / "f"), resume=True, verbose=False)
    assert resumed["summary"]["finished"] and _leaves_equal(straight["state"], resumed["state"])
    with open(tmp_path / "e" / "episodes.csv") as fa, open(tmp_path / "f" / "episodes.csv") as fb:
        assert fa.read() == fb.read()
