"""PettingZoo views: PettingZoo's own API and seed tests, agreement with the simulator, batching, bad input."""

from __future__ import annotations

import functools
import warnings

import jax
import numpy as np
import pytest

pytest.importorskip("pettingzoo")
from pettingzoo.test import parallel_api_test, parallel_seed_test  # noqa: E402

import envs_jax  # noqa: E402
from envs_jax.views import BatchedPettingZooDrivingEnv, InvalidAction, PettingZooDrivingEnv, ResetNeeded  # noqa: E402

SCENARIOS = ["merge", "roundabout", "intersection", "racetrack"]
# short episodes so that every test sees episode ends; intersection's random start offsets off
# where a test compares runs whose reset keys differ
OVERRIDES = {"merge": {}, "roundabout": {}, "intersection": {"start_noise": 0.0}, "racetrack": {"duration": 6.0}}


@functools.lru_cache(maxsize=None)
def core(name: str, deterministic: bool = False):
    """One simulator per scenario for the whole module (views built on it share its compiled step)."""
    return envs_jax.make(name, **(OVERRIDES[name] if deterministic else {}))


def random_actions(view, rng, agents):
    spec = view.spec
    if spec.discrete:
        return {a: int(rng.integers(0, spec.num_actions)) for a in agents}
    return {a: rng.uniform(-1, 1, spec.action_dim).astype(np.float32) for a in agents}


@pytest.mark.parametrize("name", SCENARIOS)
def test_pettingzoo_api_and_seed_tests_pass(name):
    env = core(name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the checkers warn on missing keys, revived agents, ...
        parallel_api_test(PettingZooDrivingEnv(env), num_cycles=1000)
        parallel_seed_test(lambda: PettingZooDrivingEnv(env))


@pytest.mark.parametrize("name", SCENARIOS)
def test_pettingzoo_episode_matches_the_simulator(name):
    """Every step equals the simulator's with the same actions; finished agents drive IDLE / zero."""
    env = core(name)
    view = PettingZooDrivingEnv(env, safe=True)
    rng = np.random.default_rng(1)
    obs, _ = view.reset(seed=3)
    # the same episode in the simulator: the view draws its reset key from the seeded generator
    key = view._key
    state = view._state
    np.testing.assert_array_equal(np.stack([obs[a] for a in view.possible_agents]), np.asarray(env.observe(state)))
    finished_seen = False
    while view.agents:
        live = list(view.agents)
        actions = random_actions(view, rng, live)
        full = np.array(view.spec.idle())
        for i, a in enumerate(view.possible_agents):
            if a in actions:
                full[i] = actions[a]
        key, key_step = jax.random.split(key)
        o2, state, r2, c2, _, info2 = env.step(key_step, state, full)
        obs, rewards, costs, terms, truncs, infos = view.step(actions)
        assert set(obs) == set(rewards) == set(costs) == set(terms) == set(infos) == set(live)
        for i, a in enumerate(view.possible_agents):
            if a not in live:
                finished_seen = True
                continue
            np.testing.assert_array_equal(obs[a], np.asarray(o2[i]))
            assert rewards[a] == pytest.approx(float(r2[i]))
            assert costs[a] == infos[a]["cost"] == pytest.approx(float(c2[i]))
            assert terms[a] == bool(info2["terminated"][i]) and truncs[a] == bool(info2["truncated"])
            assert bool(infos[a]["crashed"]) == bool(info2["crashed"][i])
        assert view.agents == [a for a in live if not (terms[a] or truncs[a])]
        np.testing.assert_array_equal(view.state(), np.asarray(o2).reshape(-1))
    assert bool(info2["truncated"]) or bool(np.all(info2["terminated"]))
    if not finished_seen:  # nobody finished early: every agent ended on the same step
        assert all(terms.values()) or all(truncs.values())


def test_pettingzoo_render_draws_the_cars():
    env = core("racetrack")
    view = PettingZooDrivingEnv(env, render_mode="rgb_array")
    view.reset(seed=0)
    first = view.render()
    assert first.dtype == np.uint8 and first.ndim == 3 and first.shape[2] == 3
    for _ in range(3):
        view.step({a: np.zeros(view.spec.action_dim, np.float32) for a in view.agents})
    second = view.render()
    assert first.shape == second.shape and np.any(first != second)  # the cars moved
    assert PettingZooDrivingEnv(env).render() is None  # no render_mode: a warning and None


def test_pettingzoo_bad_input():
    env = core("merge")
    view = PettingZooDrivingEnv(env)
    with pytest.raises(ResetNeeded, match="reset"):
        view.step({"agent_0": 1, "agent_1": 1})
    with pytest.raises(ValueError, match="render_mode"):
        PettingZooDrivingEnv(env, render_mode="human")
    view.reset(seed=0)
    cases = [({"agent_0": 1, "agent_1": 1, "agent_7": 1}, "unknown agent.*agent_7"),
             ({"agent_0": 1}, "no action for live agent.*agent_1"),
             ({"agent_0": 1, "agent_1": 5}, "agent_1 must be an integer in 0..4"),
             ({"agent_0": -1, "agent_1": 1}, "agent_0 must be an integer in 0..4"),
             ({"agent_0": 1.0, "agent_1": 1}, "dtype float"),
             ({"agent_0": True, "agent_1": 1}, "dtype bool"),
             ({"agent_0": np.array([1, 1]), "agent_1": 1}, "shape"),
             ([1, 1], "must be a dict")]
    for actions, match in cases:
        with pytest.raises(InvalidAction, match=match):
            view.step(actions)
    with pytest.raises(ValueError, match="unknown agent"):
        view.action_space("agent_9")
    cont = PettingZooDrivingEnv(core("intersection"))
    cont.reset(seed=0)
    for actions, match in [({"agent_0": np.array([np.nan], np.float32), "agent_1": np.zeros(1, np.float32)}, "finite"),
                           ({"agent_0": np.zeros(2, np.float32), "agent_1": np.zeros(1, np.float32)}, "shape"),
                           ({"agent_0": np.array([1]), "agent_1": np.zeros(1, np.float32)}, "dtype int")]:
        with pytest.raises(InvalidAction, match=match):
            cont.step(actions)
    # a finished agent's only valid action is None; after the episode, step needs a reset
    view.reset(seed=0)
    while len(view.agents) == 2:
        *_, = view.step({a: 3 for a in view.agents})
    if view.agents:
        gone = [a for a in view.possible_agents if a not in view.agents][0]
        with pytest.raises(InvalidAction, match="already finished"):
            view.step({**{a: 1 for a in view.agents}, gone: 1})
        view.step({**{a: 1 for a in view.agents}, gone: None})  # accepted
    while view.agents:
        view.step({a: 1 for a in view.agents})
    with pytest.raises(ResetNeeded, match="episode is over"):
        view.step({})


@pytest.mark.parametrize("name", SCENARIOS)
def test_batched_pettingzoo_equals_independent_views(name):
    """N batched environments agree with N single views given the same actions, resets included."""
    env = core(name, deterministic=True)  # resets independent of the key, so the runs can be compared
    n, steps = 3, 26
    batched = BatchedPettingZooDrivingEnv(env, n, safe=True)
    singles = [PettingZooDrivingEnv(env) for _ in range(n)]
    obs_b, _ = batched.reset(seed=0)
    obs_s = [s.reset(seed=k)[0] for k, s in enumerate(singles)]
    rng = np.random.default_rng(0)
    agents = batched.possible_agents
    resets = 0
    for _ in range(steps):
        for k in range(n):
            for a in singles[k].agents:  # a finished car's observation is not reported by the single view
                np.testing.assert_allclose(obs_b[a][k], obs_s[k][a], rtol=1e-4, atol=1e-3)  # vmapped vs single float32: last-ulp differences
        per_env = [random_actions(singles[k], rng, agents) for k in range(n)]
        actions = {a: np.stack([np.asarray(per_env[k][a]) for k in range(n)]) for a in agents}
        obs_b, rew_b, cost_b, term_b, trunc_b, info_b = batched.step(actions)
        for k, single in enumerate(singles):
            live = list(single.agents)
            obs_k, rew_k, term_k, trunc_k, info_k = single.step({a: per_env[k][a] for a in live})
            for a in agents:
                assert bool(info_b[a]["active"][k]) == (a in live)
                if a in live:
                    assert rew_b[a][k] == pytest.approx(rew_k[a], abs=1e-4)
                    assert cost_b[a][k] == pytest.approx(info_k[a]["cost"], abs=1e-4)
                    assert term_b[a][k] == term_k[a] and trunc_b[a][k] == trunc_k[a]
                    np.testing.assert_allclose(info_b[a]["final_obs"][k], obs_k[a], rtol=1e-4, atol=1e-3)  # vmapped vs single float32: last-ulp differences
                else:
                    assert rew_b[a][k] == 0.0 and cost_b[a][k] == 0.0
            assert bool(info_b[agents[0]]["episode_over"][k]) == (not single.agents)
            if not single.agents:
                resets += 1
                obs_s[k] = single.reset()[0]
            else:
                obs_s[k] = {**obs_s[k], **obs_k}
    assert resets >= n  # every environment finished at least one episode
    assert batched.state().shape == (n, len(agents) * batched.spec.obs_dim)


def test_batched_pettingzoo_bad_input():
    env = core("merge")
    batched = BatchedPettingZooDrivingEnv(env, 4)
    with pytest.raises(ResetNeeded):
        batched.step({a: np.ones(4, np.int64) for a in batched.possible_agents})
    batched.reset(seed=0)
    for actions, match in [({"agent_0": np.ones(4, np.int64)}, "missing \\['agent_1'\\]"),
                           ({"agent_0": np.ones(4, int), "agent_1": np.ones(4, int), "x": 1}, "unknown \\['x'\\]"),
                           ({"agent_0": np.ones(3, int), "agent_1": np.ones(4, int)}, "shape \\(4,\\)"),
                           ({"agent_0": np.full(4, 9), "agent_1": np.ones(4, int)}, "in 0..4")]:
        with pytest.raises(InvalidAction, match=match):
            batched.step(actions)
    with pytest.raises(ValueError, match="num_envs"):
        BatchedPettingZooDrivingEnv(env, 0)
