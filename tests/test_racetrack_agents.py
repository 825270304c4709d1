"""The authors' racetrack with K agents (``racetrack-k``, docs/scenarios.md "racetrack with K agents").

Truths: the two-agent ``racetrack`` env (K = 2 without traffic must reproduce it step for step under x64), the
circuit's closed-form geometry (the starting grid on the a->b straight), and the two-agent terms applied to each
agent of a larger grid.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from envs_jax import lane_locate as LL
from envs_jax.scenarios import racetrack_agents as RK
from tests.two_agent_parity import compare


def _actions(episodes, steps, seed, k=2, d=1):
    """Smooth random steering: a random walk in [-1, 1], so some episodes stay on the road for long."""
    rng = np.random.default_rng(seed)
    scale = rng.uniform(0.02, 0.3, (episodes, 1, k, d))
    walk = np.cumsum(rng.normal(size=(episodes, steps, k, d)) * scale, axis=1)
    return jnp.asarray(np.clip(walk, -1.0, 1.0))


def _compare_with_two_agent_env(episodes: int, steps: int, seed: int, action_mode: str = "lateral"):
    actions = _actions(episodes, steps, seed, d=2 if action_mode == "both" else 1)
    two = ("racetrack", {} if action_mode == "lateral" else {"action_mode": action_mode})
    return compare(two, ("racetrack-k", {"controlled_vehicles": 2, "action_mode": action_mode}), actions)


def test_two_agents_reproduce_the_two_agent_racetrack(x64):
    lengths, out = _compare_with_two_agent_env(episodes=4, steps=60, seed=0)
    assert max(lengths) >= 20  # not only instant departures from the road


@pytest.mark.slow
@pytest.mark.parametrize("action_mode", ["lateral", "both"])
def test_two_agents_reproduce_the_two_agent_racetrack_many_episodes(x64, action_mode):
    lengths, out = _compare_with_two_agent_env(episodes=16, steps=200, seed=1, action_mode=action_mode)
    assert np.any(~out["on_road"]) and all(n >= 1 for n in lengths)


def test_starting_grid_is_two_abreast_ten_metres_apart(x64):
    env = envs_jax.make("racetrack-k", controlled_vehicles=8, other_vehicles=7)
    _, st = env.reset(jax.random.key(3))
    k = np.arange(8)
    # lane (a, b, i) runs from (42, 5 i) to (100, 5 i): s along it is x - 42
    np.testing.assert_allclose(np.asarray(st.x[:8]), 42.0 + RK.START_S - RK.ROW_SPACING * (k // 2), atol=1e-12)
    np.testing.assert_allclose(np.asarray(st.y[:8]), 5.0 * (k % 2), atol=1e-12)
    np.testing.assert_allclose(np.asarray(st.heading[:8]), 0.0, atol=1e-12)
    np.testing.assert_allclose(np.asarray(st.speed), [10.0] * 8 + [RK.TRAFFIC_SPEED] * 7)
    # one traffic vehicle per section from b->c to h->i, centred on its lane, 15 m or more from every vehicle
    lane, s, lat, _ = LL.locate(env.road.lanes, st.x, st.y, st.heading)
    road = env.road
    roads = [(str(road.road_from[road.lane_road[i]]), str(road.road_to[road.lane_road[i]]))
             for i in np.asarray(lane)[8:]]
    assert roads == [(RK.SECTIONS[j + 1], RK.SECTIONS[j + 2]) for j in range(7)]
    assert [int(road.lane_id[i]) for i in np.asarray(lane)[8:]] == [j % 2 for j in range(7)]
    np.testing.assert_allclose(np.asarray(lat[8:]), 0.0, atol=1e-9)
    x, y = np.asarray(st.x), np.asarray(st.y)
    gaps = np.hypot(x[:, None] - x, y[:, None] - y) + np.diag(np.full(15, np.inf))
    assert gaps[8:].min() >= 15.0
    assert env.obs_shape == (8, 32) and env.action_shape == (8, 1)


def test_each_row_of_the_grid_drives_as_the_two_agent_pair(x64):
    """K = 6 without traffic: row r (agents 2r, 2r + 1) is the two-agent scenario started 10 r m further back
    (``start_s``); until vehicles of different rows come within 6 m of each other, every agent's state, reward,
    cost and termination equal the two-agent env's under the same actions."""
    steps = 40
    actions = _actions(3, steps, seed=5, k=6)
    k6 = envs_jax.make("racetrack-k", controlled_vehicles=6)
    two = envs_jax.make("racetrack")

    def run(env, params, acts):
        _, st0 = env.reset(jax.random.key(0), params)

        def body(st, a):
            _, st, reward, cost, done, info = env._step_jit(jax.random.key(1), st, a, params)[:6]
            return st, dict(x=st.x[:a.shape[0]], y=st.y[:a.shape[0]], reward=reward, cost=cost,
                            terminated=info["terminated"])

        return jax.device_get(jax.lax.scan(body, st0, acts)[1])

    compared = 0
    for e in range(3):
        big = run(k6, k6.default_params, actions[e])
        xy = np.stack([big["x"], big["y"]], -1)  # [T, 6, 2]
        dist = np.linalg.norm(xy[:, :, None] - xy[:, None], axis=-1)
        row = np.arange(6) // 2
        close = ((dist < 6.0) & (row[:, None] != row[None])).any((1, 2))
        n = int(np.argmax(close)) if close.any() else steps
        for r in range(3):
            params = two.default_params.replace(start_s=RK.START_S - RK.ROW_SPACING * r)
            pair = run(two, params, actions[e][:, 2 * r:2 * r + 2])
            m = n
            done_pair = np.flatnonzero(pair["terminated"].all(1))
            if done_pair.size:
                m = min(m, int(done_pair[0]) + 1)
            for key in ("x", "y", "reward", "cost"):
                np.testing.assert_allclose(big[key][:m, 2 * r:2 * r + 2], pair[key][:m], rtol=0, atol=1e-9,
                                           err_msg=f"episode {e}, row {r}: {key}")
            np.testing.assert_array_equal(big["terminated"][:m, 2 * r:2 * r + 2], pair["terminated"][:m])
            compared += m
    assert compared >= 30  # the rows were compared over real driving, not only the first step


def test_bad_values_are_refused():
    with pytest.raises(ValueError, match="controlled_vehicles must be an integer in 2..8"):
        envs_jax.make("racetrack-k", controlled_vehicles=9)
    with pytest.raises(ValueError, match="other_vehicles must be an integer in 0..7"):
        envs_jax.make("racetrack-k", other_vehicles=8)
    with pytest.raises(ValueError, match="action_mode must be one of lateral, longitudinal, both"):
        envs_jax.make("racetrack-k", action_mode="steer")
    with pytest.raises(ValueError, match=r"unknown parameter\(s\) \['lanes'\]"):
        envs_jax.make("racetrack-k", lanes=3)
    with pytest.raises(ValueError, match="collision_reward must differ from 1"):
        envs_jax.make("racetrack-k", collision_reward=1.0)
    with pytest.raises(ValueError, match="action_mode does not apply"):
        envs_jax.make("racetrack-v0", action_mode="both")


# ------------------------------------------------------------------------------------------ training wiring
@pytest.mark.slow
@pytest.mark.parametrize("algo, hierarchy", [("cs-maddpg", "0|1|2"), ("mappo-l", None)])
def test_cli_trains_racetrack_with_three_agents(tmp_path, capsys, algo, hierarchy):
    import json
    import os

    from train import __main__ as cli

    out = str(tmp_path / "run")
    argv = ["--scenario", "racetrack", "--agents", "3", "--algo", algo, "--seeds", "2", "--eval-episodes", "2",
            "--out", out]
    if algo == "cs-maddpg":
        argv += ["--hierarchy", hierarchy, "--steps", "300", "--num-envs", "2", "--chunk-steps", "150",
                 "--set", "checkpoint_every=300",
                 "--set", "warmup=64", "--set", "batch_size=16"]
    else:
        argv += ["--steps", "512", "--num-envs", "8", "--chunk-steps", "256", "--set", "rollout_length=16",
                 "--set", "num_minibatches=2"]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert f"python -m train.render --checkpoint {out}" in printed
    summary = json.load(open(os.path.join(out, "summary.json")))
    assert summary["finished"] and summary["config"]["agents"] == 3
    assert len(summary["eval"]["leader_return"]["per_seed"]) == 2
    assert all(np.isfinite(v["per_seed"]).all() for v in summary["eval"].values() if isinstance(v, dict))


@pytest.mark.slow
def test_pettingzoo_checker_passes():
    """PettingZoo's own API checker on the framework view of the K-agent task."""
    import warnings

    from pettingzoo.test import parallel_api_test

    from envs_jax.views import PettingZooDrivingEnv

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        env = envs_jax.make("racetrack-k", controlled_vehicles=3, other_vehicles=2)
        parallel_api_test(PettingZooDrivingEnv(env), num_cycles=30)
