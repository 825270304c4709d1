"""merge-k (the authors' merge with K agents on the traffic core): with K = 2 and no traffic it reproduces the
two-agent ``merge`` step for step under x64; the K-agent placement, arrival ranking and observation against
independent transcriptions; config errors; jit/vmap roll-outs with the training wrapper."""

from __future__ import annotations

import functools
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from envs_jax import nearest_view
from envs_jax import vehicle as Veh
from envs_jax.scenarios import merge_agents as MA
from envs_jax.scenarios.arrival import one_shot_arrival, ranked_arrival
from envs_jax.traffic_autoreset import TrafficAutoResetWrapper

KEY = jax.random.key(0)
TOL = 1e-9  # K = 2 parity under x64: every float of every step within this (absolute)
STEPS = 20  # the merge's time limit (20 s at one decision per second)


# ----------------------------------------------------------------------------------------------
# K = 2 reproduces the two-agent merge

def _two_agent_run(env, init_x, init_speed, actions):
    params = env.default_params.replace(init_x=init_x, init_speed=init_speed)
    obs0, st = env.reset(KEY, params)

    def body(st, a):
        obs, st, r, c, done, info = env.step(KEY, st, a, params)
        return st, dict(x=st.x, y=st.y, heading=st.heading, speed=st.speed, crashed=st.crashed, obs=obs, reward=r,
                        cost=c, terminated=info["terminated"], done=done, arrived=st.arrived,
                        first_arrived=st.first_arrived, truncated=info["truncated"])

    return obs0, jax.lax.scan(body, st, actions)[1]


def _merge_k_run(env, init_x, init_speed, actions):
    params = env.default_params
    init = dict(x=init_x, y=jnp.array([MA.HIGHWAY_Y, MA.RAMP_Y]), heading=0.0, speed=init_speed, alive=True,
                delta=params.idm.delta)
    obs0, st = env.state_from(init, params)

    def body(st, a):
        obs, st, r, c, done, info = env.step(KEY, st, a, params)
        return st, dict(x=st.x, y=st.y, heading=st.heading, speed=st.speed, crashed=st.crashed, obs=obs, reward=r,
                        cost=c, terminated=info["terminated"], done=done, arrived=st.arrived,
                        first_arrived=st.first_arrived, truncated=info["truncated"])

    return obs0, jax.lax.scan(body, st, actions)[1]


def _compare_with_two_agent_merge(episodes):
    """``episodes`` random-action episodes from (jittered) starts; returns the counts of crashes and arrivals seen."""
    rng = np.random.default_rng(23)
    init_x = 70.0 + rng.uniform(-5.0, 5.0, (episodes, 2))
    init_x[0] = 70.0  # the default start
    init_speed = rng.uniform(20.0, 30.0, (episodes, 2))
    init_speed[0] = 25.0
    actions = jnp.asarray(rng.integers(0, 5, (episodes, STEPS, 2)), jnp.int32)
    two = envs_jax.make("merge")
    many = envs_jax.make("merge-k", controlled_vehicles=2)
    obs_a, rec_a = jax.jit(jax.vmap(functools.partial(_two_agent_run, two)))(init_x, init_speed, actions)
    obs_b, rec_b = jax.jit(jax.vmap(functools.partial(_merge_k_run, many)))(init_x, init_speed, actions)
    assert rec_b["x"].dtype == jnp.float64 and rec_b["obs"].shape == rec_a["obs"].shape == (episodes, STEPS, 2, 8)
    np.testing.assert_allclose(obs_b, obs_a, rtol=0, atol=TOL)
    for name in ("x", "y", "heading", "speed", "obs", "reward", "cost"):
        np.testing.assert_allclose(rec_b[name], rec_a[name], rtol=0, atol=TOL, err_msg=name)
    for name in ("crashed", "terminated", "done", "arrived", "first_arrived", "truncated"):
        np.testing.assert_array_equal(rec_b[name], rec_a[name], err_msg=name)
    # the default start reproduces the two-agent reset without injection
    obs_reset, st_reset = many.reset(KEY)
    np.testing.assert_array_equal(obs_reset, two.reset(KEY)[0])
    np.testing.assert_array_equal(st_reset.x, two.reset(KEY)[1].x)
    return int(np.sum(np.any(rec_a["crashed"][:, -1], -1))), int(np.sum(rec_a["arrived"][:, -1]))


def test_k2_reproduces_two_agent_merge(x64):
    _compare_with_two_agent_merge(2)


@pytest.mark.slow
def test_k2_reproduces_two_agent_merge_many_episodes(x64):
    crashes, arrivals = _compare_with_two_agent_merge(16)
    assert crashes > 0 and arrivals > 0  # both outcomes were exercised


# ----------------------------------------------------------------------------------------------
# K agents: placement, ranking, observation

@functools.cache
def env_of(k, others=0, **kw):
    return envs_jax.make("merge-k", controlled_vehicles=k, other_vehicles=others, **kw)


@pytest.mark.parametrize("k,others", [(3, 0), (4, 0), (4, 10), (8, 10)])
def test_initial_placement(k, others):
    env = env_of(k, others)
    obs, st = env.reset(KEY)
    road = env.road
    col = road.lanes.np_col
    x, y, h = (np.asarray(a, np.float64) for a in (st.x, st.y, st.heading))
    highway = {road.lane("a", "b", 1)}  # agents: right highway lane (even k) or ramp (odd k)
    ramp = {road.lane("j", "k", 0)}
    left = {road.lane("a", "b", 0)}  # other vehicles: left lane, then the right lane ahead of the agents
    right = {road.lane("a", "b", 1), road.lane("b", "c", 1)}
    allowed = [highway if i % 2 == 0 else ramp for i in range(k)]
    allowed += [left if i < MA.TRAFFIC_LEFT else right for i in range(others)]
    for i, lanes in enumerate(allowed):
        lane = int(st.lane[i])
        assert lane in lanes, (i, lane)
        dx, dy = x[i] - col("start_x")[lane], y[i] - col("start_y")[lane]
        s = dx * col("dir_x")[lane] + dy * col("dir_y")[lane]
        lat = -dx * col("dir_y")[lane] + dy * col("dir_x")[lane]
        assert 0 <= s <= col("length")[lane], (i, s)
        assert abs(lat) + Veh.WIDTH / 2 <= col("width")[lane] / 2, (i, lat)
        assert h[i] == pytest.approx(np.arctan2(col("dir_y")[lane], col("dir_x")[lane]), abs=1e-12)
        assert bool(st.on_road[i])
    for i, j in itertools.combinations(range(k + others), 2):  # axis-aligned rectangles (every heading is 0)
        assert abs(x[i] - x[j]) >= Veh.LENGTH or abs(y[i] - y[j]) >= Veh.WIDTH, (i, j)
    assert obs.shape == (k, 4 * k) and not np.any(st.crashed)


def _brute_arrival(sequence, first_reward=10.0, second_reward=5.0):
    """The ranking rule read literally: agents in order, each seeing who arrived before it."""
    k = len(sequence[0])
    arrived, first, out = [False] * k, 0, []
    for here in sequence:
        bonus = [0.0] * k
        for i in range(k):
            if here[i] and not arrived[i]:
                someone = any(arrived[j] for j in range(k) if j != i)
                bonus[i] = second_reward if someone else first_reward
                first = first if someone else i + 1
                arrived[i] = True
        out.append((bonus, list(arrived), first))
    return out


def _ranked_sequence(sequence):
    def body(carry, here):
        bonus, arrived, first = ranked_arrival(here, *carry, 10.0, 5.0)
        return (arrived, first), (bonus, arrived, first)

    k = sequence.shape[-1]
    return jax.lax.scan(body, (jnp.zeros(k, bool), jnp.zeros((), jnp.int32)), sequence)[1]


@pytest.mark.parametrize("k,length", [(3, 3), (4, 2)])
def test_arrival_ranking_exhaustive(k, length):
    """Every sequence of arrival patterns of the given length (ties, late arrivals, repeated presence)."""
    patterns = list(itertools.product([False, True], repeat=k))
    sequences = np.array(list(itertools.product(patterns, repeat=length)))  # [S, length, k]
    bonus, arrived, first = jax.jit(jax.vmap(_ranked_sequence))(jnp.asarray(sequences))
    for s, seq in enumerate(sequences):
        for t, (b, a, f) in enumerate(_brute_arrival(seq.tolist())):
            assert np.asarray(bonus[s, t]).tolist() == b and np.asarray(arrived[s, t]).tolist() == a
            assert int(first[s, t]) == f, (seq.tolist(), t)


def test_arrival_ranking_hand_made():
    seqs = {((0, 0, 1), (1, 1, 1)): [[0, 0, 10], [5, 5, 0]],  # agent 2 first, then a tie of 0 and 1
            ((0, 1, 1, 0), (1, 0, 0, 1)): [[0, 10, 5, 0], [5, 0, 0, 5]],  # tie: agent order decides
            ((1, 1, 1, 1),): [[10, 5, 5, 5]]}
    for seq, expected in seqs.items():
        bonus = _ranked_sequence(jnp.asarray(seq, bool))[0]
        assert np.asarray(bonus).tolist() == expected


def test_ranking_is_the_two_agent_rule_for_two():
    cases = itertools.product(itertools.product([False, True], repeat=2), itertools.product([False, True], repeat=2),
                              [0, 1, 2])
    two, many = (jax.jit(functools.partial(f, first_reward=10.0, second_reward=5.0))
                 for f in (one_shot_arrival, ranked_arrival))
    for arrived, here, first in cases:
        a = two(jnp.array(here), jnp.array(arrived), jnp.int32(first))
        b = many(jnp.array(here), jnp.array(arrived), jnp.int32(first))
        for u, v in zip(a, b):
            np.testing.assert_array_equal(u, v)


def test_arrival_in_the_env():
    """K = 4 with the line at x = 80 m and IDLE: agents 0 and 1 (x = 70) cross on step 1, the tie going to agent 0;
    agents 2 and 3 (x = 50, at 75 m after step 1) on step 2, both second."""
    env = env_of(4, finish_x=80.0)
    _, st = env.reset(KEY)
    idle = jnp.full(4, Veh.IDLE, jnp.int32)
    _, st, r1, _, done1, info1 = env.step(KEY, st, idle)
    _, st, r2, _, done2, info2 = env.step(KEY, st, idle)
    assert np.asarray(r1).tolist() == [12.0, 7.0, 2.0, 2.0] and np.asarray(r2).tolist() == [2.0, 2.0, 7.0, 7.0]
    assert int(info2["first_arrived"]) == 1 and np.all(info2["arrived"]) and bool(done2) and not bool(done1)


def _brute_view(x, y, h, v, alive, agents, count):
    feats = np.stack([x, y, v * np.cos(h), v * np.sin(h)], -1)
    rows = []
    for a in agents:
        near = sorted((np.hypot(x[j] - x[a], y[j] - y[a]), j) for j in range(len(x)) if j != a and alive[j])
        row = [feats[a]] + [feats[j] if d < 200.0 else np.zeros(4) for d, j in near[:count - 1]]
        row += [np.zeros(4)] * (count - len(row))
        rows.append(np.concatenate(row))
    return np.stack(rows)


@pytest.mark.parametrize("count", [1, 2, 4, 7])
def test_observation_against_brute_force(count):
    rng = np.random.default_rng(count)
    x = rng.uniform(0, 400, 7)
    y = rng.uniform(0, 15, 7)
    x[5], y[5] = x[0] + 3.0, y[0]  # equidistant from agent 0 with slot 6: the lower slot comes first
    x[6], y[6] = x[0] - 3.0, y[0]
    x[4] = x[1] + 250.0  # beyond the perception distance of agent 1
    h = rng.uniform(-0.3, 0.3, 7)
    v = rng.uniform(15, 30, 7)
    alive = np.array([True, True, True, False, True, True, True])
    got = nearest_view.observe(jnp.asarray(x), jnp.asarray(y), jnp.asarray(h), jnp.asarray(v), jnp.asarray(alive),
                               np.arange(7), 3, count)
    np.testing.assert_allclose(got, _brute_view(x, y, h, v, alive, (0, 1, 2), count), rtol=1e-6, atol=1e-4)


# ----------------------------------------------------------------------------------------------
# configuration, jit and vmap, the training wrapper

@pytest.mark.parametrize("bad,what", [
    ({"controlled_vehicles": 1}, "2..8"), ({"controlled_vehicles": 9}, "2..8"), ({"controlled_vehicles": 2.5}, "2..8"),
    ({"controlled_vehicles": True}, "2..8"), ({"other_vehicles": 11}, "other_vehicles"),
    ({"observed_vehicles": 4}, "observed_vehicles"), ({"observed_vehicles": 0}, "observed_vehicles"),
    ({"collision_cost": -1.0}, "collision_cost"), ({"target_speeds": [30, 20]}, "target_speeds"),
    ({"lanes_count": 3}, "unknown"), ({"idm": {"speed": 1}}, "idm")])
def test_bad_config(bad, what):
    with pytest.raises(ValueError, match=what):
        envs_jax.make("merge-k", **bad)


@pytest.mark.parametrize("k,others", [(3, 2), (4, 0)])
def test_jit_vmap_rollout(k, others):
    """Random actions through the training wrapper (auto-reset across episodes): shapes, dtypes, finite values."""
    wrapped = TrafficAutoResetWrapper(env_of(k, others))
    steps = STEPS + 5

    def run(key, actions):
        obs, st = wrapped.reset(key)

        def body(st, a):
            obs, st, r, c, done, info = wrapped.step(key, st, a)
            return st, (obs, r, c, done, info["episode_arrived"], info["arrived"])

        return obs, jax.lax.scan(body, st, actions)[1]

    actions = jnp.asarray(np.random.default_rng(k).integers(0, 5, (2, steps, k)), jnp.int32)
    obs0, (obs, r, c, done, ep_arrived, arrived) = jax.jit(jax.vmap(run))(jax.random.split(KEY, 2), actions)
    assert obs0.shape == (2, k, 4 * k) and obs.shape == (2, steps, k, 4 * k)
    assert r.shape == c.shape == (2, steps, k) and r.dtype == jnp.float32 and obs.dtype == jnp.float32
    assert np.all(np.isfinite(obs)) and np.all(np.isfinite(r)) and np.all(np.isfinite(c))
    assert np.all(np.any(np.asarray(done)[:, :STEPS], axis=1))  # the time limit ends each first episode by then
    np.testing.assert_array_equal(ep_arrived, arrived)  # latched flags reported to the training metrics


@pytest.mark.slow
def test_cli_trains_merge_with_three_agents(tmp_path, capsys):
    """``python -m train --scenario merge --agents 3``: a short CSQ run writes per-episode rows whose arrivals come
    from merge-k's latched flags, and its evaluation."""
    import csv
    import json
    import os

    from train import __main__ as cli

    out = str(tmp_path / "run")
    assert cli.main(["--scenario", "merge", "--agents", "3", "--algo", "csq", "--steps", "400", "--seeds", "1",
                     "--chunk-steps", "200", "--set", "warmup=64", "--set", "batch_size=16", "--eval-episodes", "2",
                     "--out", out]) == 0
    assert "merge/csq" in capsys.readouterr().out
    with open(os.path.join(out, "episodes.csv")) as f:
        rows = list(csv.DictReader(f))
    assert rows and all(1 <= int(r["length"]) <= STEPS for r in rows)
    # the arrival flags reach the training records (an agent that neither crashes nor stops crosses x = 350)
    assert any(r["leader_arrived"] == "1" or r["follower_arrived"] == "1" for r in rows)
    summary = json.load(open(os.path.join(out, "summary.json")))
    assert summary["finished"] and summary["config"]["agents"] == 3 and len(summary["config"]["cost_threshold"]) == 3
