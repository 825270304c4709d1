"""benchmarks/env_throughput.py and baseline_sims.py: the simulators compared run the same task, the task
auto-reset restarts finished episodes, and the growth exponent of vehicle_scaling.py recovers a known power."""

import functools
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))

import baseline_sims  # noqa: E402
import env_throughput  # noqa: E402
import envs_jax  # noqa: E402
import vehicle_scaling  # noqa: E402

TASKS = [t for t in ("highway-v0", "highway-fast-v0") if t in envs_jax.available_tasks()]


@functools.lru_cache(maxsize=None)
def _ours(task):
    """The task's environment and its description (built once per module)."""
    env = envs_jax.make(task)
    return env, env_throughput.describe_jax(env)


@pytest.mark.parametrize("task", TASKS)
def test_same_task_as_highway_env(task):
    """envs_jax's task and highway-env's own (gymnasium.make) agree on vehicles, frequencies, duration, shapes."""
    ours = _ours(task)[1]
    theirs = baseline_sims.describe_highway_env(task)
    assert env_throughput.differences(ours, theirs) == []
    assert ours["vehicles"] == theirs["vehicles"] > 1


@pytest.mark.parametrize("task", TASKS)
def test_same_task_as_envpool(task):
    pytest.importorskip("envpool")
    assert env_throughput.differences(_ours(task)[1], baseline_sims.describe_envpool(task)) == []


@pytest.mark.parametrize("task", ["intersection-v1", "intersection-multi-agent-v0"])
def test_intersection_tasks_agree_with_highway_env_but_for_the_random_vehicle_count(task):
    """The multi-agent task's tuple spaces are described per controlled vehicle ([K, ...], one action space);
    the vehicles on the road at reset are a random draw of the warm-up (spawns, clears), so only they may differ."""
    ours = _ours(task)[1]
    theirs = baseline_sims.describe_highway_env(task)
    assert [d.split(":")[0] for d in env_throughput.differences(ours, theirs)] in ([], ["vehicles"])
    if task == "intersection-multi-agent-v0":
        assert theirs["controlled"] == ours["controlled"] == 2
        assert theirs["obs_shape"] == ours["obs_shape"] == [2, 15, 7] and theirs["actions"] == 3
    result = baseline_sims.measure_highway_env(task, seconds=0.3, repeats=1)  # tuple actions step the env
    assert result["steps"] >= 1 and result["steps_per_s"] > 0


def test_envpool_two_player_task_steps_with_one_action_per_player():
    """EnvPool's intersection-multi-agent-v0 holds two players per environment: the benchmark sends one action per
    player, synchronously and asynchronously, and counts environment steps (not player steps)."""
    pytest.importorskip("envpool")
    desc = baseline_sims.describe_envpool("intersection-multi-agent-v0")
    assert desc["controlled"] == 2 and desc["obs_shape"][0] == 2
    for num_envs, batch in ((2, 2), (4, 2)):
        row = baseline_sims.measure_envpool("intersection-multi-agent-v0", num_envs, batch, seconds=0.3, repeats=1,
                                            num_threads=1)
        assert row["steps_per_s"] > 0 and row["batch_size"] == batch


def test_differences_names_what_disagrees():
    ours = {"vehicles": 51, "simulation_frequency": 15, "duration": 40.0, "obs_shape": [5, 5], "actions": 5}
    theirs = dict(ours, vehicles=5, duration=40, obs_shape=[15, 7], actions=3)
    diff = env_throughput.differences(ours, theirs)
    assert [d.split(":")[0] for d in diff] == ["vehicles", "obs_shape", "actions"]


def test_task_auto_reset_restarts_finished_episodes():
    """A 2-second highway-fast-v0 episode ends on its second step; the wrapper then holds a fresh episode
    (time 0, as after reset), and before that it steps exactly as the bare environment."""
    env = _ours("highway-fast-v0")[0]
    wrapped = env_throughput.TaskAutoReset(env)
    params = env.default_params.replace(duration=2.0)
    obs, state = wrapped.reset(jax.random.key(0), params)
    action = jnp.array([1])
    key = jax.random.key(1)
    obs1, st1, _, _, done1, _ = wrapped.step(key, state, action, params)
    bare_obs, bare_st, _, _, bare_done, _ = env.step(jax.random.split(key)[0], state, action, params)
    assert not bool(done1) and not bool(bare_done)
    np.testing.assert_array_equal(np.asarray(obs1), np.asarray(bare_obs))
    np.testing.assert_array_equal(np.asarray(st1.x), np.asarray(bare_st.x))
    _, st2, _, _, done2, _ = wrapped.step(jax.random.key(2), st1, action, params)
    assert bool(done2)
    assert int(st2.time) == 0
    fresh = env.reset(jax.random.split(jax.random.key(2))[1], params)[1]
    np.testing.assert_array_equal(np.asarray(st2.x), np.asarray(fresh.x))


@pytest.mark.parametrize("power", [1.0, 2.0, 0.5])
def test_exponent_recovers_a_power_law(power):
    slots = np.array([11, 26, 51, 101])
    steps_per_s = 3e5 / slots ** power
    assert vehicle_scaling.exponent(slots, steps_per_s) == pytest.approx(power, abs=1e-9)


_SPLIT_ROLLOUT = """
import json, sys
import jax
jax.config.update("jax_num_cpu_devices", 2)
sys.path.insert(0, "benchmarks")
import envs_jax
from env_throughput import TaskAutoReset, jax_runner
env = envs_jax.make("merge-v0")  # a traffic task: sparse_map's data-dependent loops inside each device's program
key = jax.random.key(1)
split = jax_runner(env, 8, 40, TaskAutoReset, devices=2)
alone = jax_runner(env, 4, 40, TaskAutoReset, devices=1)
halves = [int(alone(k)) for k in jax.random.split(key, 2)]
print(json.dumps({"devices": len(jax.devices()), "split": int(split(key)), "halves": halves}))
"""


def test_rollout_split_over_devices_is_each_devices_own_rollout():
    # env_throughput's --devices: with 2 CPU devices, 8 envs run as two independent 4-env roll-outs, one per
    # device, each from its half of the key; the episode count is their sum.
    import json
    import subprocess

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    env = dict(os.environ, XLA_FLAGS="")
    out = subprocess.run([sys.executable, "-c", _SPLIT_ROLLOUT], cwd=root, env=env, capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res["devices"] == 2
    # precondition: the two halves end different numbers of episodes, so a split that ran one half twice, or
    # mixed the halves' environments, would show in the sum
    assert res["halves"][0] != res["halves"][1], res
    assert res["split"] == sum(res["halves"])
