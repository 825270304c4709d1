"""The authors' intersection with K agents (``intersection-k``, docs/scenarios.md "intersection with K agents").

Truths: the two-agent ``intersection`` env (K = 2 must reproduce it step for step under x64 from the same starts),
the junction's closed-form geometry (placements, arrival times at constant speed) and the ranked arrival rule.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax

PARITY_TOL = 1e-9  # x64; the two programs compute the same expressions
APPROACH, CROSSING, OUTER = 100.0, 22.0, 11.0  # approach lane length, straight crossing, centre to lane end [m]


@functools.lru_cache(maxsize=None)
def _episodes_fn(name: str, x64: bool, **kw):
    """Jitted, vmapped fixed-length episodes from given start offsets: agent state, rewards, costs, flags, views."""
    env = envs_jax.make(name, **kw)

    def episode(start_s, actions):
        params = env.default_params.replace(start_s=start_s, start_noise=0.0)
        obs0, st0 = env.reset(jax.random.key(0), params)

        def body(st, action):
            obs, st, reward, cost, done, info = env._step_jit(jax.random.key(1), st, action, params)[:6]
            out = dict(obs=obs, x=st.x, y=st.y, heading=st.heading, speed=st.speed, crashed=st.crashed,
                       on_road=st.on_road, arrived=st.arrived, reward=reward, cost=cost,
                       terminated=info["terminated"], truncated=info["truncated"], done=done)
            return st, out

        _, out = jax.lax.scan(body, st0, actions)
        return dict(obs=obs0, x=st0.x, y=st0.y, heading=st0.heading, speed=st0.speed), out

    return env, jax.jit(jax.vmap(episode))


def _compare_with_two_agent_env(episodes: int, seed: int, action_mode: str = "longitudinal"):
    rng = np.random.default_rng(seed)
    d = 2 if action_mode == "both" else 1
    start_s = jnp.asarray(rng.uniform(45.0, 75.0, (episodes, 2)))  # some pairs meet at the crossing, some not
    actions = jnp.asarray(rng.uniform(-1.0, 1.0, (episodes, 20, 2, d)) * rng.uniform(0.1, 1.0, (episodes, 1, 1, 1)))
    mode = {} if action_mode == "longitudinal" else {"action_mode": action_mode}
    _, two = _episodes_fn("intersection", True, **mode)
    _, k2 = _episodes_fn("intersection-k", True, controlled_vehicles=2, action_mode=action_mode)
    (init_a, out_a), (init_b, out_b) = jax.device_get(two(start_s, actions)), jax.device_get(k2(start_s, actions))
    for key in init_a:
        np.testing.assert_allclose(init_b[key], init_a[key], rtol=0, atol=PARITY_TOL, err_msg=key)
    for e in range(episodes):
        done = np.asarray(out_a["done"][e])
        n = int(np.argmax(done)) + 1 if done.any() else 20
        for key in ("obs", "x", "y", "heading", "speed", "reward", "cost"):
            np.testing.assert_allclose(out_b[key][e, :n], out_a[key][e, :n], rtol=0, atol=PARITY_TOL,
                                       err_msg=f"episode {e}: {key}")
        for key in ("crashed", "on_road", "arrived", "terminated", "truncated", "done"):
            np.testing.assert_array_equal(out_b[key][e, :n], out_a[key][e, :n], err_msg=f"episode {e}: {key}")
    return out_a


def test_two_agents_reproduce_the_two_agent_intersection(x64):
    out = _compare_with_two_agent_env(episodes=8, seed=0)
    assert out["crashed"].any() and out["arrived"].any()  # the sample meets both outcomes


@pytest.mark.slow
@pytest.mark.parametrize("action_mode", ["longitudinal", "both"])
def test_two_agents_reproduce_the_two_agent_intersection_many_episodes(x64, action_mode):
    out = _compare_with_two_agent_env(episodes=32, seed=1, action_mode=action_mode)
    assert out["crashed"].any() and out["arrived"].any() and (~out["on_road"]).any()  # every outcome occurs


def test_one_agent_per_arm_and_a_second_wave(x64):
    env = envs_jax.make("intersection-k", controlled_vehicles=8, start_noise=0.0)
    _, st = env.reset(jax.random.key(0))
    start_s = np.asarray(env.default_params.start_s)
    np.testing.assert_allclose(start_s, [61.0] * 4 + [41.0] * 4)
    for k in range(8):
        arm = k % 4
        c, s = math.cos(math.radians(90 * arm)), math.sin(math.radians(90 * arm))
        # the south approach runs from (2, 111) to (2, 11); arm a is it turned by 90 a degrees
        px, py = 2.0, APPROACH + OUTER - start_s[k]
        np.testing.assert_allclose([st.x[k], st.y[k]], [c * px - s * py, s * px + c * py], atol=1e-9)
        heading = math.atan2(-c, s)  # (0, -1) turned by 90 a degrees
        assert math.isclose(math.cos(float(st.heading[k]) - heading), 1.0, abs_tol=1e-12)
    np.testing.assert_allclose(np.asarray(st.speed), 10.0)
    assert env.obs_shape == (8, 32) and env.action_shape == (8, 1)


def test_staggered_agents_arrive_in_order_and_are_ranked(x64):
    """Four agents, one per arm, 20 m apart in start offset, driving at a constant 10 m/s: each reaches its exit
    at s = 5 after ``127 - start_s`` metres, i.e. on decision ceil((127 - start_s) / 10); the first earns 5, the
    later ones 2, on top of the speed reward 2; nobody crashes."""
    start_s = [61.0, 41.0, 21.0, 1.0]
    env = envs_jax.make("intersection-k", controlled_vehicles=4, start_s=start_s, start_noise=0.0)
    _, st = env.reset(jax.random.key(0))
    rewards, first = [], []
    for _ in range(14):
        _, st, reward, cost, done, info = env.step(jax.random.key(1), st, jnp.zeros((4, 1)))
        rewards.append(np.asarray(reward))
        first.append(int(info["first_arrived"]))
    rewards = np.array(rewards)
    arrival = [math.ceil((APPROACH + CROSSING + 5.0 - s) / 10.0) - 1 for s in start_s]  # step index
    assert arrival == [6, 8, 10, 12]
    for k, t in enumerate(arrival):
        assert rewards[t, k] == 2.0 + (5.0 if k == 0 else 2.0)
        others = np.delete(np.arange(14), t)
        np.testing.assert_array_equal(rewards[others, k], 2.0)
    assert first[5] == 0 and first[6:] == [1] * 8 and not np.asarray(st.crashed).any()


def test_bad_values_are_refused():
    with pytest.raises(ValueError, match="controlled_vehicles must be an integer in 2..8"):
        envs_jax.make("intersection-k", controlled_vehicles=9)
    with pytest.raises(ValueError, match="vehicles_count must be an integer in 2..3"):
        envs_jax.make("intersection-k", controlled_vehicles=3, vehicles_count=4)
    with pytest.raises(ValueError, match="action_mode must be one of longitudinal, lateral, both"):
        envs_jax.make("intersection-k", action_mode="steer")
    with pytest.raises(ValueError, match=r"start_s must be 3 numbers in 0..100"):
        envs_jax.make("intersection-k", controlled_vehicles=3, start_s=[61, 61])
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['other_vehicles'\]"):
        envs_jax.make("intersection-k", other_vehicles=2)
    with pytest.raises(ValueError, match="speed_band_low .* must not exceed"):
        envs_jax.make("intersection-k", speed_band_low=13.0)


# ------------------------------------------------------------------------------------------ training wiring
@pytest.mark.slow
def test_cli_trains_intersection_with_four_agents(tmp_path, capsys):
    import json
    import os

    from train import __main__ as cli

    out = str(tmp_path / "run")
    assert cli.main(["--scenario", "intersection", "--agents", "4", "--algo", "cs-maddpg", "--hierarchy", "0,1|2,3",
                     "--seeds", "2", "--eval-episodes", "2", "--steps", "300", "--num-envs", "2", "--chunk-steps",
                     "150", "--set", "checkpoint_every=300", "--set", "warmup=64", "--set", "batch_size=16",
                     "--out", out]) == 0
    assert f"python -m train.render --checkpoint {out}" in capsys.readouterr().out
    summary = json.load(open(os.path.join(out, "summary.json")))
    assert summary["finished"] and summary["config"]["agents"] == 4
    assert all(np.isfinite(v["per_seed"]).all() for v in summary["eval"].values() if isinstance(v, dict))


@pytest.mark.slow
def test_pettingzoo_checker_passes():
    """PettingZoo's own API checker on the framework view of the K-agent task."""
    import warnings

    from pettingzoo.test import parallel_api_test

    from envs_jax.views import PettingZooDrivingEnv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        parallel_api_test(PettingZooDrivingEnv(envs_jax.make("intersection-k", controlled_vehicles=3)), num_cycles=30)
