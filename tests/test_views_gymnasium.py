"""Gymnasium views: ``check_env`` on every scenario and on single-agent traffic tasks, agreement with the
simulator, the vector env, bad input."""

from __future__ import annotations

import functools
import warnings

import jax
import numpy as np
import pytest

gymnasium = pytest.importorskip("gymnasium")
from gymnasium.utils.env_checker import check_env  # noqa: E402

import envs_jax  # noqa: E402
from envs_jax.views import GymnasiumDrivingEnv, GymnasiumVectorDrivingEnv, idle_policy, random_policy  # noqa: E402

SCENARIOS = ["merge", "roundabout", "intersection", "racetrack"]
# check_env's warnings that are facts of these tasks, not API faults: absolute coordinates are
# unbounded, and a view built directly (not through gymnasium.make) has no spec
EXPECTED_WARNINGS = ("infinity. This is probably too", "not having a spec")


@functools.lru_cache(maxsize=None)
def _make(name: str, **overrides):
    return envs_jax.make(name, **overrides)


# traffic tasks, by test id: few vehicles and short episodes (one controlled vehicle unless K2)
TASKS = {"highway-fast-v0": ("highway-fast-v0", (("vehicles_count", 3), ("duration", 4))),
         "highway-fast-v0-K2": ("highway-fast-v0",
                                (("controlled_vehicles", 2), ("vehicles_count", 3), ("duration", 4))),
         "racetrack-v0": ("racetrack-v0", (("other_vehicles", 1), ("duration", 3)))}


def core(name: str, deterministic: bool = False):
    """One simulator per scenario or task (intersection's random start offsets off where runs with different
    reset keys are compared); views on it share its compiled functions."""
    if name in TASKS:
        return _make(TASKS[name][0], **dict(TASKS[name][1]))
    return _make(name, **({"start_noise": 0.0} if deterministic and name == "intersection" else {}))


@functools.lru_cache(maxsize=None)
def idle(name: str, deterministic: bool = False):
    """One partner policy object per simulator, so that views of agent 0 share one compiled step."""
    return idle_policy(core(name, deterministic))


@pytest.mark.parametrize("name", SCENARIOS)
def test_check_env_passes_for_each_agent_view(name):
    env = core(name)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(GymnasiumDrivingEnv(env, agent=0, partner_policy=idle(name), render_mode="rgb_array"))
    unexpected = [str(w.message) for w in caught if not any(s in str(w.message) for s in EXPECTED_WARNINGS)]
    assert not unexpected


@pytest.mark.parametrize("name", ["merge", "racetrack"])
def test_single_agent_view_matches_the_simulator(name):
    """The viewed agent's transitions equal the simulator's with the partner's policy applied."""
    env = core(name)
    partner = random_policy(env)
    view = GymnasiumDrivingEnv(env, agent=1, partner_policy=partner, safe=True)
    obs, _ = view.reset(seed=5)
    key, state = view._key, view._state
    view.action_space.seed(0)
    np.testing.assert_array_equal(obs, np.asarray(env.observe(state))[1])
    for _ in range(200):
        action = view.action_space.sample()
        key, key_step = jax.random.split(key)
        key_partner, key_core = jax.random.split(key_step)
        other = np.asarray(partner(key_partner, env.observe(state)[:1]))  # agent 0 is the partner
        full = np.concatenate([other.reshape((1,) + np.shape(action)), np.asarray(action)[None]]).astype(
            np.int32 if env.discrete else np.float32)
        o2, state, r2, c2, _, info2 = env.step(key_core, state, full)
        obs, reward, cost, terminated, truncated, info = view.step(action)
        np.testing.assert_allclose(obs, np.asarray(o2)[1], rtol=1e-6, atol=1e-5)
        assert reward == pytest.approx(float(r2[1]), abs=1e-5) and cost == info["cost"] == pytest.approx(float(c2[1]))
        assert terminated == bool(info2["terminated"][1]) and truncated == bool(info2["truncated"])
        if terminated or truncated:
            break
    assert terminated or truncated


def test_multi_agent_env_without_partner_policy_points_at_the_multi_agent_views():
    env = core("merge")
    with pytest.raises(ValueError, match="2 agents.*partner_policy.*PettingZooDrivingEnv.*JaxMARLDrivingEnv"):
        GymnasiumDrivingEnv(env)
    with pytest.raises(ValueError, match="2 agents.*partner_policy"):
        GymnasiumVectorDrivingEnv(env, 4)
    with pytest.raises(ValueError, match="agent must be an index in 0..1"):
        GymnasiumDrivingEnv(env, agent=2, partner_policy=idle_policy(env))
    with pytest.raises(ValueError, match="partner_policy must return"):
        view = GymnasiumDrivingEnv(env, partner_policy=lambda key, obs: np.zeros(3, np.int32))
        view.reset(seed=0)
        view.step(1)


def test_gymnasium_bad_input():
    env = core("merge")
    view = GymnasiumDrivingEnv(env, partner_policy=idle("merge"))
    with pytest.raises(gymnasium.error.ResetNeeded):
        view.step(1)
    view.reset(seed=0)
    for action, match in [(5, "in 0..4"), (-1, "in 0..4"), (1.0, "dtype float"), (np.array([1, 2]), "shape"),
                          (None, "must be an integer")]:
        with pytest.raises(ValueError, match=match):
            view.step(action)
        with pytest.raises(gymnasium.error.InvalidAction):
            view.step(action)
    terminated = truncated = False
    while not (terminated or truncated):
        _, _, terminated, truncated, _ = view.step(3)
    with pytest.raises(ValueError, match="episode ended"):
        view.step(1)
    cont = GymnasiumDrivingEnv(core("racetrack"), partner_policy=idle("racetrack"))
    cont.reset(seed=0)
    for action, match in [(np.array([np.inf], np.float32), "finite"), (np.zeros(2, np.float32), "shape"),
                          (np.array([1]), "dtype int")]:
        with pytest.raises(ValueError, match=match):
            cont.step(action)


@pytest.mark.parametrize("name,mode", [  # both modes, a discrete and a continuous scenario in the default suite
    ("merge", "next_step"), pytest.param("roundabout", "same_step", marks=pytest.mark.slow),
    pytest.param("intersection", "next_step", marks=pytest.mark.slow), ("racetrack", "same_step")])
def test_vector_env_equals_single_views(name, mode):
    """next_step and same_step auto-reset agree with independent single views fed the same actions."""
    env = core(name, deterministic=True)
    n = 3
    partner = idle(name, True)
    for mode in (mode,):
        vec = GymnasiumVectorDrivingEnv(env, n, partner_policy=partner, autoreset_mode=mode, safe=True)
        assert vec.metadata["autoreset_mode"].value == {"next_step": "NextStep", "same_step": "SameStep"}[mode]
        singles = [GymnasiumDrivingEnv(env, partner_policy=partner) for _ in range(n)]
        obs_v, _ = vec.reset(seed=0)
        obs_s = np.stack([s.reset(seed=k)[0] for k, s in enumerate(singles)])
        pending = np.zeros(n, bool)  # next_step: single envs that ended and reset on the next call
        vec.action_space.seed(1)
        episodes = 0
        for _ in range(45):
            np.testing.assert_allclose(obs_v, obs_s, rtol=1e-4, atol=1e-3)  # vmapped float32: last-ulp differences
            actions = vec.action_space.sample()
            obs_v, rew_v, cost_v, term_v, trunc_v, info_v = vec.step(actions)
            for k, single in enumerate(singles):
                if pending[k]:
                    obs_s[k] = single.reset()[0]
                    pending[k] = False
                    assert rew_v[k] == 0 and not term_v[k] and not trunc_v[k] and not info_v["_cost"][k]
                    continue
                o, r, te, tr, info = single.step(actions[k])
                assert rew_v[k] == pytest.approx(r, abs=1e-4) and cost_v[k] == pytest.approx(info["cost"], abs=1e-4)
                assert (term_v[k], trunc_v[k]) == (te, tr)
                assert info_v["_cost"][k] and info_v["cost"][k] == pytest.approx(info["cost"], abs=1e-4)
                obs_s[k] = o
                if te or tr:
                    episodes += 1
                    if mode == "same_step":
                        assert info_v["_final_obs"][k]
                        np.testing.assert_allclose(info_v["final_obs"][k], o, rtol=1e-4, atol=1e-3)
                        obs_s[k] = single.reset()[0]
                    else:
                        pending[k] = True
        assert episodes >= n
    with pytest.raises(ValueError, match="shape \\(3,"):
        vec.step(np.zeros((2,) + vec.single_action_space.shape, vec.single_action_space.dtype))


SLOW = pytest.mark.slow  # a further compilation of the simulator


@pytest.mark.parametrize("name", ["highway-fast-v0", pytest.param("racetrack-v0", marks=SLOW)])
def test_check_env_passes_on_single_agent_tasks(name):
    """A K = 1 task is a plain gymnasium.Env (no partner policy): [5, 5] Kinematics, [2, 12, 12] occupancy grid."""
    env = core(name)
    view = GymnasiumDrivingEnv(env, render_mode="rgb_array")
    assert view.observation_space.shape == tuple(env.obs_shape[1:])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(view)
    unexpected = [str(w.message) for w in caught if not any(s in str(w.message) for s in EXPECTED_WARNINGS)]
    assert not unexpected
    assert np.all(np.isfinite(view.observation_space.low)) == (name == "racetrack-v0")  # highway-env's bounds
    frame = view.render()
    assert frame.dtype == np.uint8 and frame.shape[2] == 3
    assert GymnasiumDrivingEnv(env).render() is None  # no render_mode: Gymnasium's warning and None


@pytest.mark.parametrize("name", ["highway-fast-v0", pytest.param("racetrack-v0", marks=SLOW)])
def test_single_agent_task_view_is_the_task(name):
    """Each transition equals the simulator's own step with the view's key, until the episode ends."""
    env = core(name)
    view = GymnasiumDrivingEnv(env, safe=True)
    obs, _ = view.reset(seed=2)
    state = view._state
    view.action_space.seed(0)
    for _ in range(100):
        key_step = jax.random.split(view._key)[1]  # the key the view's next step uses
        action = view.action_space.sample()
        o2, state, r2, c2, _, info2 = env.step(jax.random.split(key_step)[1], state, np.asarray(action)[None])
        obs, reward, cost, terminated, truncated, info = view.step(action)
        np.testing.assert_array_equal(obs, np.asarray(o2)[0])
        assert reward == pytest.approx(float(r2[0])) and cost == info["cost"] == pytest.approx(float(c2[0]))
        assert terminated == bool(info2["terminated"][0]) and truncated == bool(info2["truncated"])
        if terminated or truncated:
            break
    assert terminated or truncated
    with pytest.raises(gymnasium.error.ResetNeeded):
        view.step(action)


@SLOW
def test_task_with_two_agents_needs_a_partner_and_passes_check_env_with_one():
    env = core("highway-fast-v0-K2")
    with pytest.raises(ValueError, match="2 agents.*partner_policy"):
        GymnasiumDrivingEnv(env)
    partner = random_policy(env)  # gets the other agent's [1, 5, 5] observations
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(GymnasiumDrivingEnv(env, agent=1, partner_policy=partner))
    assert not [str(w.message) for w in caught if not any(s in str(w.message) for s in EXPECTED_WARNINGS)]


def test_gymnasium_bad_input_on_a_task():
    view = GymnasiumDrivingEnv(core("highway-fast-v0"))
    with pytest.raises(gymnasium.error.ResetNeeded):
        view.step(1)
    view.reset(seed=0)
    for action, match in [(5, "in 0..4"), (1.0, "dtype float"), (np.array([1]), "shape"), (None, "must be an integer")]:
        with pytest.raises(gymnasium.error.InvalidAction, match=match):
            view.step(action)
    with pytest.raises(ValueError, match="agent must be an index in 0..0"):
        GymnasiumDrivingEnv(core("highway-fast-v0"), agent=1)


@SLOW
def test_vector_env_on_a_task_steps_like_the_simulator():
    """same_step auto-reset of N single-agent highway environments against the simulator's own step and reset."""
    env = core("highway-fast-v0")
    n = 3
    vec = GymnasiumVectorDrivingEnv(env, n, autoreset_mode="same_step", safe=True)
    assert vec.single_observation_space.shape == (5, 5) and vec.observation_space.shape == (n, 5, 5)
    obs, _ = vec.reset(seed=0)
    vec.action_space.seed(0)
    episodes = 0
    for _ in range(9):
        states, key = jax.device_get(vec._states), vec._key
        actions = vec.action_space.sample()
        obs, rewards, costs, terms, truncs, infos = vec.step(actions)
        keys = jax.random.split(jax.random.split(key)[1], n)  # the view's key for each environment
        for e in range(n):
            key_step, key_reset = jax.random.split(keys[e])
            o, _, r, c, _, info = env.step(jax.random.split(key_step)[1], jax.tree.map(lambda x, e=e: x[e], states),
                                           np.asarray(actions[e])[None])
            assert rewards[e] == pytest.approx(float(r[0]), abs=1e-4)
            assert costs[e] == pytest.approx(float(c[0]), abs=1e-4)
            assert (terms[e], truncs[e]) == (bool(info["terminated"][0]), bool(info["truncated"]))
            assert infos["_cost"][e] and set(infos["rewards"]) >= {"collision_reward", "_collision_reward"}
            if terms[e] or truncs[e]:
                episodes += 1
                assert infos["_final_obs"][e]
                np.testing.assert_allclose(infos["final_obs"][e], o[0], rtol=1e-4, atol=1e-3)
                np.testing.assert_allclose(obs[e], env.reset(key_reset)[0][0], rtol=1e-4, atol=1e-3)
            else:
                np.testing.assert_allclose(obs[e], o[0], rtol=1e-4, atol=1e-3)
    assert episodes >= n  # 4 s episodes
