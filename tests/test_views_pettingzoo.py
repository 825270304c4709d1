"""PettingZoo views: PettingZoo's own API and seed tests, agreement with the simulator, batching, bad input,
on the two-agent scenarios and on the traffic tasks."""

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
# the long ones: one discrete and one continuous scenario in the default suite, the others under slow
DEFAULT_TWO = ["merge", pytest.param("roundabout", marks=pytest.mark.slow),
               pytest.param("intersection", marks=pytest.mark.slow), "racetrack"]
# short episodes so that every test sees episode ends; intersection's random start offsets off
# where a test compares runs whose reset keys differ
OVERRIDES = {"merge": {}, "roundabout": {}, "intersection": {"start_noise": 0.0}, "racetrack": {"duration": 6.0}}


# traffic tasks, by test id: few vehicles and short episodes, so that tests compile little and see episode ends
TASKS = {"highway-fast-v0-K1": ("highway-fast-v0", {"vehicles_count": 3, "duration": 4}),
         "highway-fast-v0-K2": ("highway-fast-v0", {"controlled_vehicles": 2, "vehicles_count": 3, "duration": 4}),
         "racetrack-v0": ("racetrack-v0", {"other_vehicles": 1, "duration": 3}),
         "intersection-multi-agent-v0": ("intersection-multi-agent-v0", {"initial_vehicle_count": 3})}


@functools.lru_cache(maxsize=None)
def core(name: str, deterministic: bool = False):
    """One simulator per scenario or task for the whole module (views built on it share its compiled step)."""
    if name in TASKS:
        return envs_jax.make(TASKS[name][0], **TASKS[name][1])
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


SLOW = pytest.mark.slow  # a further compilation of the simulator (intersection's alone costs more than the rest)


@pytest.mark.parametrize("name", ["highway-fast-v0-K2", "racetrack-v0", pytest.param("highway-fast-v0-K1", marks=SLOW),
                                  pytest.param("intersection-multi-agent-v0", marks=SLOW)])
def test_pettingzoo_checkers_pass_on_traffic_tasks(name):
    """PettingZoo's own checkers on Kinematics ([n, F]) and occupancy-grid ([C, H, W]) tasks, K = 1 and K = 2;
    the spaces have the env's per-agent shape, the state is every observation flattened, frames draw the cars."""
    env = core(name)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        parallel_api_test(PettingZooDrivingEnv(env), num_cycles=40)
        parallel_seed_test(lambda: PettingZooDrivingEnv(env))
    view = PettingZooDrivingEnv(env, render_mode="rgb_array")
    obs, _ = view.reset(seed=0)
    k = env.num_agents
    assert view.possible_agents == [f"agent_{i}" for i in range(k)]
    for a in view.possible_agents:
        assert view.observation_space(a).shape == tuple(env.obs_shape[1:]) == obs[a].shape
    bounded = name == "racetrack-v0"  # highway-env's OccupancyGrid space is [-1, 1]; Kinematics' is unbounded
    assert np.all(np.isfinite(view.observation_space("agent_0").low)) == bounded
    assert view.state().shape == view.state_space.shape == (k * int(np.prod(env.obs_shape[1:])),)
    np.testing.assert_array_equal(view.state(), np.concatenate([obs[a].reshape(-1) for a in view.possible_agents]))
    frame = view.render()
    assert frame.dtype == np.uint8 and frame.ndim == 3 and frame.shape[2] == 3
    green = np.all(frame == np.array([50, 200, 0], np.uint8), axis=-1)  # controlled cars: highway-env's EGO_COLOR
    assert green.sum() > 10


@pytest.mark.parametrize("name", SCENARIOS + ["highway-fast-v0-K2", pytest.param("intersection-multi-agent-v0",
                                                                                  marks=SLOW)])
def test_pettingzoo_episode_matches_the_simulator(name):
    """Every step equals the simulator's with the same actions; finished agents drive IDLE / zero."""
    env = core(name)
    view = PettingZooDrivingEnv(env, safe=True)
    rng = np.random.default_rng(1)
    obs, _ = view.reset(seed=3)
    # the same episode in the simulator: the view draws its reset key from the seeded generator
    key = view._key
    state = view._state
    if name in SCENARIOS:  # (a task's observation recomputed eagerly would cost a compilation per operation)
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


@pytest.mark.parametrize("name", DEFAULT_TWO)
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
                # vmapped vs single float32: last-ulp differences
                np.testing.assert_allclose(obs_b[a][k], obs_s[k][a], rtol=1e-4, atol=1e-3)
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
                    # vmapped vs single float32: last-ulp differences
                    np.testing.assert_allclose(info_b[a]["final_obs"][k], obs_k[a], rtol=1e-4, atol=1e-3)
                else:
                    assert rew_b[a][k] == 0.0 and cost_b[a][k] == 0.0
            assert bool(info_b[agents[0]]["episode_over"][k]) == (not single.agents)
            if not single.agents:
                resets += 1
                obs_s[k] = single.reset()[0]
            else:
                obs_s[k] = {**obs_s[k], **obs_k}
    assert resets >= n  # every environment finished at least one episode
    assert batched.state().shape == (n, len(agents) * batched.spec.obs_size)


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


@SLOW
def test_batched_pettingzoo_on_a_traffic_task_steps_like_the_simulator():
    """Each of N batched highway environments (K = 2) steps as the simulator does from the same state with the
    same key: live agents' actions, finished agents driven IDLE with zero reward, reset once all finished."""
    env = core("highway-fast-v0-K2")
    n, k = 3, env.num_agents
    batched = BatchedPettingZooDrivingEnv(env, n, safe=True)
    agents = batched.possible_agents
    obs, _ = batched.reset(seed=0)
    rng = np.random.default_rng(0)
    active = np.ones((n, k), bool)
    resets = 0
    for _ in range(10):
        states, key = jax.device_get(batched._states), batched._key
        actions = {a: rng.integers(0, 5, n) for a in agents}
        obs, rewards, costs, terms, truncs, infos = batched.step(actions)
        keys = jax.random.split(jax.random.split(key)[1], n)  # the view's key for each environment
        for e in range(n):
            key_step, key_reset = jax.random.split(keys[e])
            full = np.array([actions[a][e] if active[e, i] else 1 for i, a in enumerate(agents)], np.int32)
            o, _, r, c, _, info = env.step(key_step, jax.tree.map(lambda x, e=e: x[e], states), full)
            for i, a in enumerate(agents):
                assert bool(infos[a]["active"][e]) == active[e, i]
                if active[e, i]:
                    assert rewards[a][e] == pytest.approx(float(r[i]), abs=1e-4)
                    assert costs[a][e] == infos[a]["cost"][e] == pytest.approx(float(c[i]), abs=1e-4)
                    assert terms[a][e] == bool(info["terminated"][i]) and truncs[a][e] == bool(info["truncated"])
                    np.testing.assert_allclose(infos[a]["final_obs"][e], o[i], rtol=1e-4, atol=1e-3)
                else:
                    assert rewards[a][e] == 0.0 and costs[a][e] == 0.0
            still = active[e] & ~(np.asarray(info["terminated"]) | bool(info["truncated"]))
            assert bool(infos[agents[0]]["episode_over"][e]) == (not still.any())
            if still.any():
                active[e] = still
                expected = o
            else:
                active[e] = True
                resets += 1
                expected = env.reset(key_reset)[0]
            for i, a in enumerate(agents):
                np.testing.assert_allclose(obs[a][e], expected[i], rtol=1e-4, atol=1e-3)
    assert resets >= n  # 4 s episodes: every environment reset at least once
    assert batched.state().shape == (n, k * 25)
    assert set(infos["agent_0"]["rewards"]) >= {"collision_reward", "high_speed_reward"}  # reward terms, [N] each


def _bad_actions(view, cases):
    for actions, match in cases:
        with pytest.raises(InvalidAction, match=match):
            view.step(actions)


def test_pettingzoo_bad_input_on_traffic_tasks():
    """Highway's five meta-actions and racetrack's steering-only action are what the views accept."""
    view = PettingZooDrivingEnv(core("highway-fast-v0-K2"))
    with pytest.raises(ResetNeeded, match="reset"):
        view.step({"agent_0": 1, "agent_1": 1})
    view.reset(seed=0)
    _bad_actions(view, [({"agent_0": 1, "agent_1": 5}, "agent_1 must be an integer in 0..4 .*4=SLOWER"),
                        ({"agent_0": 1}, "no action for live agent.*agent_1"),
                        ({"agent_0": 1, "agent_1": 1, "agent_2": 1}, "unknown agent.*agent_2"),
                        ({"agent_0": np.array([1, 1]), "agent_1": 1}, "shape"),
                        ({"agent_0": 1.0, "agent_1": 1}, "dtype float")])
    race = PettingZooDrivingEnv(core("racetrack-v0"))
    race.reset(seed=0)
    assert race.action_space("agent_0").shape == (1,)
    for actions, match in [({"agent_0": np.zeros(2, np.float32)}, "shape \\(1,\\)"),
                           ({"agent_0": np.array([np.nan], np.float32)}, "finite"),
                           ({"agent_0": 1}, "dtype int"),
                           ({"agent_0": np.zeros(1, np.float32), "agent_1": np.zeros(1, np.float32)}, "unknown agent")]:
        with pytest.raises(InvalidAction, match=match):
            race.step(actions)


@SLOW
def test_pettingzoo_bad_input_at_the_intersection():
    """The intersection's three meta-actions (lateral=False) are named in the error."""
    view = PettingZooDrivingEnv(core("intersection-multi-agent-v0"))
    view.reset(seed=0)
    assert view.action_space("agent_0").n == 3
    _bad_actions(view, [({"agent_0": 1, "agent_1": 3},
                         "agent_1 must be an integer in 0..2 \\(0=SLOWER, 1=IDLE, 2=FASTER\\)"),
                        ({"agent_0": -1, "agent_1": 1}, "agent_0 must be an integer in 0..2")])


def test_pettingzoo_agents_without_a_vehicle_are_not_in_the_episode():
    """merge-cavs-v0 draws 1-3 controlled vehicles per episode (easy traffic): after reset the view lists exactly
    the agents whose slot holds a vehicle (read from the simulator's own state), every count occurs over the seeds,
    and an episode's agents never include an absent one."""
    from envs_jax.scenarios.merge_cavs import agents_alive

    env = envs_jax.make("merge-cavs-v0", traffic_density=1)
    pz = PettingZooDrivingEnv(env)
    counts = set()
    for seed in range(12):
        obs, infos = pz.reset(seed=seed)
        alive = np.asarray(agents_alive(env, pz._state))
        expected = [a for a, p in zip(pz.possible_agents, alive) if p]
        assert pz.agents == expected and sorted(obs) == sorted(expected) and sorted(infos) == sorted(expected)
        counts.add(len(expected))
    assert counts == {1, 2, 3}
    pz.reset(seed=0)
    live = list(pz.agents)
    _, _, terms, truncs, _ = pz.step({a: 1 for a in live})
    assert set(terms) == set(live) and set(pz.agents) <= set(live)


@pytest.mark.slow
def test_pettingzoo_checkers_pass_with_absent_agents():
    env = envs_jax.make("merge-cavs-v0", traffic_density=1)
    parallel_api_test(PettingZooDrivingEnv(env), num_cycles=40)
