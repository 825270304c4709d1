"""The authors' roundabout with K agents (``roundabout-k``, docs/scenarios.md "roundabout with K agents").

Truths: the two-agent ``roundabout`` env (K = 2 without traffic must reproduce it step for step under x64),
the road's closed-form geometry (placements), and a plain-Python transcription of the per-agent reward, cost and
termination rule on hand-made positions.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from envs_jax import vehicle as Veh
from envs_jax.scenarios import roundabout_agents as RA
from tests.two_agent_parity import compare

DIAGONAL = math.hypot(Veh.LENGTH, Veh.WIDTH)  # centres farther apart than this cannot overlap


def _compare_with_two_agent_env(episodes: int, steps: int, seed: int):
    actions = jnp.asarray(np.random.default_rng(seed).integers(0, 5, (episodes, steps, 2)), jnp.int32)
    return compare(("roundabout", {}), ("roundabout-k", {"controlled_vehicles": 2}), actions)


def test_two_agents_reproduce_the_two_agent_roundabout(x64):
    lengths, out = _compare_with_two_agent_env(episodes=2, steps=20, seed=0)
    assert lengths == [20, 20]  # full episodes (the 20 s limit)


@pytest.mark.slow
def test_two_agents_reproduce_the_two_agent_roundabout_many_episodes(x64):
    lengths, out = _compare_with_two_agent_env(episodes=12, steps=20, seed=1)
    # the sample exercises crashes and arrivals, not only driving
    assert np.any(out["crashed"]) and np.any(out["reward"] >= 5)
    assert all(n >= 1 for n in lengths)


# ------------------------------------------------------------------------------------------ placement
# closed forms: access road of each compass entry (a straight line, heading), and the exit lane's line
ENTRY = {"w": (lambda x, y: abs(y - 2.0), 0.0), "s": (lambda x, y: abs(x - 2.0), -math.pi / 2),
         "e": (lambda x, y: abs(y + 2.0), math.pi), "n": (lambda x, y: abs(x + 2.0), math.pi / 2)}
SIDE = "wsen"  # agent k enters from SIDE[k % 4]


def _angle_diff(a, b):
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


@pytest.mark.parametrize("k,n", [(3, 0), (4, 8), pytest.param(8, 8, marks=pytest.mark.slow)])
def test_initial_placement_is_valid(k, n):
    env = envs_jax.make("roundabout-k", controlled_vehicles=k, other_vehicles=n)
    _, st = env.reset(jax.random.key(0))
    st = jax.device_get(st)
    idx = np.asarray(env.controlled)
    assert np.all(st.on_road) and np.all(st.alive) and not np.any(st.crashed)
    for a in range(k):
        x, y, h = (float(v) for v in (st.x[idx[a]], st.y[idx[a]], st.heading[idx[a]]))
        off_line, heading = ENTRY[SIDE[a % 4]]
        assert off_line(x, y) < 1e-5 and _angle_diff(h, heading) < 1e-6, (a, x, y, h)
        assert 42.5 < math.hypot(x, y) < 170  # on the straight part of the access road
        assert float(st.speed[idx[a]]) == RA.AGENT_SPEED
    # agents 2, 3 are the half turns of agents 0, 1
    if k >= 4:
        for a in (0, 1):
            np.testing.assert_allclose([st.x[idx[a + 2]], st.y[idx[a + 2]]], [-st.x[idx[a]], -st.y[idx[a]]],
                                       atol=1e-5)
    # traffic: heading along its lane (the tangent of the ring / the access road) and on it
    lanes = env.road.lanes

    @jax.jit
    def lateral_and_tangent(lane, x, y):
        s, lat = envs_jax.lanes.local_coordinates(lanes, lane, x, y)
        return lat, envs_jax.lanes.heading_at(lanes, lane, s)

    lat, tangent = jax.device_get(lateral_and_tangent(st.lane[k:], st.x[k:], st.y[k:]))
    assert np.all(np.abs(lat) < 1e-4)
    for slot in range(k, k + n):
        assert _angle_diff(float(st.heading[slot]), float(tangent[slot - k])) < 1e-4
    # no two vehicles overlap (bounding circles apart)
    pos = np.stack([st.x, st.y], axis=1)
    gaps = np.linalg.norm(pos[:, None] - pos[None], axis=-1) + np.eye(k + n) * 1e9
    assert gaps.min() > DIAGONAL


def test_routes_lead_to_the_stated_exits():
    env = envs_jax.make("roundabout-k", controlled_vehicles=8)
    road = env.road
    roads, _, lens = env.task.agent_routes
    for a in range(8):
        slot = env.controlled[a]
        last = road.roads[int(roads[slot, int(lens[slot]) - 1])]
        assert last == (("nx", "nxs") if a % 4 in (0, 1) else ("sx", "sxs")), (a, last)
        first = road.roads[int(roads[slot, 0])]
        assert first[0] == SIDE[a % 4] + "er"


def test_bad_arguments_raise():
    with pytest.raises(ValueError, match="controlled_vehicles must be an integer in 2..8"):
        envs_jax.make("roundabout-k", controlled_vehicles=1)
    with pytest.raises(ValueError, match="controlled_vehicles must be an integer in 2..8"):
        envs_jax.make("roundabout-k", controlled_vehicles=9)
    with pytest.raises(ValueError, match="other_vehicles must be an integer in 0..8"):
        envs_jax.make("roundabout-k", other_vehicles=9)
    with pytest.raises(ValueError, match="vehicles_count must be an integer in 2..3"):
        envs_jax.make("roundabout-k", controlled_vehicles=3, vehicles_count=4)
    with pytest.raises(ValueError, match="unknown parameter"):
        envs_jax.make("roundabout-k", init_x=[0.0, 1.0])
    with pytest.raises(ValueError, match="speed_band_low"):
        envs_jax.make("roundabout-k", speed_band_low=16.0)


# ------------------------------------------------------------------------------------------ reward rule
def _exit_point(a, s):
    """A point at ``s`` along agent a's exit road (nxs->nxr: x = 2 going north; sxs->sxr: x = -2 going south)."""
    return (2.0, -42.5 - s, -math.pi / 2) if a % 4 in (0, 1) else (-2.0, 42.5 + s, math.pi / 2)


def _other_exit_point(a, s):
    return _exit_point(a + 2, s)


def _brute_force(where, s, speed, crashed):
    """The rule of docs/scenarios.md, one agent at a time: (reward, cost, terminated)."""
    arrived = where == "exit" and s >= 20.0
    reward = -5.0 * crashed + 2.0 * (10.0 <= speed <= 15.0) + 5.0 * arrived
    return reward, 5.0 * crashed, bool(crashed or arrived)


def test_arrival_rule_matches_a_python_transcription():
    k = 4
    env = envs_jax.make("roundabout-k", controlled_vehicles=k)
    params = env.default_params
    # hand-made sequences: per step and agent (where, s along the exit road, speed, crashed); the agents
    # arrive in different orders, one on the wrong exit, some near the threshold, one crashed on its exit
    seqs = [
        [("start", 0, 8, 0), ("start", 0, 12, 0), ("start", 0, 16, 0), ("start", 0, 10, 0)],
        [("exit", 19.9, 12, 0), ("exit", 25, 12, 0), ("other", 30, 12, 0), ("start", 0, 15, 0)],
        [("exit", 20.1, 12, 0), ("exit", 40, 16, 0), ("other", 50, 12, 0), ("exit", 5, 9, 0)],
        [("exit", 40, 15.5, 0), ("exit", 60, 12, 1), ("exit", 21, 12, 0), ("exit", 20.5, 11, 0)],
        [("exit", 60, 14, 1), ("start", 0, 0, 1), ("exit", 100, 12, 0), ("exit", 35, 10, 0)],
    ]
    init = jax.device_get(env.reset(jax.random.key(0))[1])
    slots = np.asarray(env.controlled)
    x, y, h = (np.tile(np.asarray(a), (len(seqs), 1)) for a in (init.x, init.y, init.heading))
    speed, crashed = np.zeros((len(seqs), k)), np.zeros((len(seqs), k), bool)
    for t, row in enumerate(seqs):
        for a, (where, s, v, c) in enumerate(row):
            if where != "start":
                point = (_exit_point if where == "exit" else _other_exit_point)(a, s)
                x[t, slots[a]], y[t, slots[a]], h[t, slots[a]] = point
            speed[t, slots[a]], crashed[t, slots[a]] = v, bool(c)

    @jax.jit
    @jax.vmap
    def outcome(x, y, h, speed, crashed):
        _, st = env.state_from(dict(x=x, y=y, heading=h, speed=speed, alive=jnp.ones(k, bool),
                                    delta=jnp.zeros(k), routes=env.task.agent_routes), params)
        st = st.replace(crashed=crashed)
        return env.task.outcome(st, st, jnp.zeros(k, jnp.int32), params)

    reward, cost, terminated, _ = jax.device_get(outcome(x, y, h, speed, crashed))
    for t, row in enumerate(seqs):
        truth = [_brute_force(*r) for r in row]
        np.testing.assert_allclose(reward[t], [r for r, _, _ in truth], err_msg=f"step {t}")
        np.testing.assert_allclose(cost[t], [c for _, c, _ in truth], err_msg=f"step {t}")
        np.testing.assert_array_equal(terminated[t], [d for _, _, d in truth], err_msg=f"step {t}")


# ------------------------------------------------------------------------------------------ jit / vmap
@pytest.mark.parametrize("k,n", [(3, 1), pytest.param(4, 8, marks=pytest.mark.slow)])
def test_random_rollout_under_jit_and_vmap(k, n):
    env = envs_jax.make("roundabout-k", controlled_vehicles=k, other_vehicles=n)
    steps, envs = 6, 3

    def rollout(key):
        obs, st = env.reset(key)

        def body(st, key):
            action = jax.random.randint(key, (k,), 0, 5)
            obs, st, reward, cost, done, info = env._step_jit(key, st, action, env.default_params)[:6]
            return st, (obs, reward, cost, done, st.x, st.speed)

        return jax.lax.scan(body, st, jax.random.split(key, steps))[1]

    obs, reward, cost, done, x, speed = jax.device_get(jax.jit(jax.vmap(rollout))(
        jax.random.split(jax.random.key(3), envs)))
    assert obs.shape == (envs, steps, k, 4 * k) and reward.shape == cost.shape == (envs, steps, k)
    assert done.shape == (envs, steps) and x.shape == speed.shape == (envs, steps, k + n)
    for a in (obs, reward, cost, x, speed):
        assert np.all(np.isfinite(a))
    assert np.all(np.abs(speed) < 40)  # highway-env's MAX_SPEED bounds every vehicle


# ------------------------------------------------------------------------------------------ training wiring
@pytest.mark.slow
def test_cli_trains_roundabout_with_three_agents(tmp_path, capsys):
    import json
    import os

    from train import __main__ as cli

    out = str(tmp_path / "run")
    assert cli.main(["--scenario", "roundabout", "--agents", "3", "--steps", "400", "--seeds", "2", "--num-envs", "2",
                     "--chunk-steps", "200", "--set", "warmup=64", "--set", "batch_size=16", "--eval-episodes", "2",
                     "--out", out]) == 0
    printed = capsys.readouterr().out
    assert f"python -m train.render --checkpoint {out}" in printed  # the renderer draws the K agents
    assert "train.experiments" not in printed  # no study of the K-agent roundabout
    summary = json.load(open(os.path.join(out, "summary.json")))
    assert summary["finished"] and summary["config"]["agents"] == 3
    assert summary["timing"]["env_steps_run"] == 400


@pytest.mark.slow
def test_pettingzoo_checkers_pass():
    """PettingZoo's own API and seed checkers on the K-agent roundabout with traffic."""
    import warnings

    from pettingzoo.test import parallel_api_test, parallel_seed_test

    from envs_jax.views import PettingZooDrivingEnv

    env = envs_jax.make("roundabout-k", controlled_vehicles=3, other_vehicles=2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(PettingZooDrivingEnv(env), num_cycles=40)
        parallel_seed_test(lambda: PettingZooDrivingEnv(env))
