"""The environment API: make/params/env_config validation, action checks, compilation, auto-reset."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax

KEY = jax.random.key(0)

AUTHORS_MERGE_CONFIG = {  # merge_env_result/exp1/env_config.json (docs/scenarios.md)
    "observation": {"type": "MultiAgentObservation",
                    "observation_config": {"type": "Kinematics", "flatten": True, "absolute": True,
                                           "see_behind": True, "normalize": False,
                                           "features": ["x", "y", "vx", "vy"], "vehicles_count": 2}},
    "action": {"type": "MultiAgentAction", "action_config": {"type": "DiscreteMetaAction"}},
    "controlled_vehicles": 2, "simulation_frequency": 15, "policy_frequency": 1, "duration": 20,
    "screen_width": 600, "screen_height": 150, "collision_reward": -1,
}


def test_unknown_scenario_lists_the_choices():
    with pytest.raises(ValueError, match="unknown scenario 'highway'.*merge.*roundabout"):
        envs_jax.make("highway")


def test_unknown_or_bad_parameters():
    with pytest.raises(ValueError, match="unknown parameter.*'speed_bonus'.*allowed"):
        envs_jax.make("merge", speed_bonus=3)
    with pytest.raises(ValueError, match="init_x.*shape"):
        envs_jax.make("merge", init_x=[1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="target_speeds"):
        envs_jax.make("merge", target_speeds=[30, 20])
    with pytest.raises(ValueError, match="policy_frequency"):
        envs_jax.make("merge", policy_frequency=0)
    with pytest.raises(ValueError, match="finite"):
        envs_jax.make("merge", duration=float("nan"))


def test_authors_env_config_is_accepted_and_unknown_keys_rejected():
    env = envs_jax.make("merge", env_config=AUTHORS_MERGE_CONFIG)
    assert env.frames == 15 and float(env.default_params.duration) == 20.0
    with pytest.raises(ValueError, match="env_config key 'lanes_count' is not understood"):
        envs_jax.make("merge", env_config={**AUTHORS_MERGE_CONFIG, "lanes_count": 3})
    with pytest.raises(ValueError, match="DiscreteMetaAction"):
        envs_jax.make("merge", env_config={"action": {"type": "ContinuousAction"}})
    with pytest.raises(ValueError, match="normalize"):
        envs_jax.make("merge", env_config={"observation": {"type": "Kinematics", "normalize": True}})
    env = envs_jax.make("roundabout", env_config={"action": {"type": "MultiAgentAction", "action_config": {
        "type": "DiscreteMetaAction", "target_speeds": [0, 4, 8, 12, 16]}}, "duration": 20})
    np.testing.assert_array_equal(env.default_params.target_speeds, [0, 4, 8, 12, 16])


@pytest.mark.parametrize("action,match", [
    (np.array([1, 1, 1]), "shape \\(2,\\)"),
    (np.array([1.0, 1.0]), "integers"),
    (np.array([1, 5]), "in 0..4"),
    (np.array([-1, 0]), "in 0..4"),
])
def test_bad_discrete_actions_raise_before_tracing(action, match):
    env = envs_jax.make("merge")
    _, state = env.reset(KEY)
    with pytest.raises(ValueError, match=match):
        env.step(KEY, state, action)


def test_traced_discrete_actions_are_clipped():
    env = envs_jax.make("merge")
    _, state = env.reset(KEY)
    step = jax.jit(env.step)
    a = step(KEY, state, jnp.array([9, 9]))  # out of range inside jit: clipped to SLOWER (4)
    b = step(KEY, state, jnp.array([4, 4]))
    np.testing.assert_array_equal(a[1].x, b[1].x)


def test_step_compiles_once_per_shape():
    env = envs_jax.make("roundabout")
    params = env.default_params
    obs, state = env.reset(KEY, params)
    step = jax.jit(env.step)
    for a in ([0, 1], [3, 4], [2, 2], [1, 3]):
        obs, state, *_ = step(KEY, state, jnp.array(a, jnp.int32), params)
    # A changed parameter value is data, not a new program.
    step(KEY, state, jnp.array([1, 1], jnp.int32), params.replace(collision_cost=7.0))
    assert step._cache_size() == 1
    batched = jax.jit(jax.vmap(env.step, in_axes=(0, 0, 0, None)))
    _, states = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(KEY, 8), params)
    batched(jax.random.split(KEY, 8), states, jnp.ones((8, 2), jnp.int32), params)
    batched(jax.random.split(KEY, 8), states, jnp.zeros((8, 2), jnp.int32), params)
    assert batched._cache_size() == 1


def test_state_exposes_vehicle_arrays():
    env = envs_jax.make("roundabout")
    obs, st = env.reset(KEY)
    for name in ("x", "y", "heading", "speed", "crashed", "on_road", "lane", "target_lane"):
        assert getattr(st, name).shape == (2,)
    np.testing.assert_allclose(np.asarray(obs), [[-45, 2, 8, 0, 2, 85, 0, -8], [2, 85, 0, -8, -45, 2, 8, 0]], atol=1e-5)
    assert env.road.lane_names[int(st.lane[0])] == ("wer", "wes", 0)


def test_params_change_rewards_costs_and_time_limit():
    env = envs_jax.make("merge", collision_cost=7.0, duration=3.0)
    _, st = env.reset(KEY)
    done = False
    for t in range(3):
        _, st, r, c, done, info = env.step(KEY, st, np.array([1, 1]))
    assert bool(done) and bool(info["truncated"]) and not bool(info["terminated"].any())
    env = envs_jax.make("merge", collision_cost=7.0)
    _, st = env.reset(KEY)
    for t in range(10):  # IDLE/IDLE: the follower hits the obstacle at t = 10
        _, st, r, c, done, info = env.step(KEY, st, np.array([1, 1]))
    assert float(c[1]) == 7.0 and float(c[0]) == 0.0 and bool(info["terminated"][1])


def test_episode_continues_after_one_agent_is_done():
    """IDLE/IDLE merge: the follower crashes at t = 10, the leader drives on and arrives at t = 12."""
    env = envs_jax.make("merge")
    _, st = env.reset(KEY)
    dones = []
    for t in range(12):
        _, st, r, c, done, info = env.step(KEY, st, np.array([1, 1]))
        dones.append((bool(done), tuple(np.asarray(info["terminated"]))))
    assert dones[9] == (False, (False, True)) and dones[11] == (True, (True, True))


def test_auto_reset_keeps_terminal_obs_and_episode_stats():
    env = envs_jax.make("merge")
    wrapped = envs_jax.AutoResetWrapper(env)
    obs0, ws = wrapped.reset(KEY)
    step = jax.jit(wrapped.step)
    for t in range(12):
        obs, ws, r, c, done, info = step(jax.random.key(t), ws, jnp.array([1, 1]))
    assert bool(info["returned_episode"])
    np.testing.assert_allclose(np.asarray(info["episode_return"]), [34.0, 9.0])
    np.testing.assert_allclose(np.asarray(info["episode_cost"]), [0.0, 15.0])
    assert int(info["episode_length"]) == 12 and bool(info["episode_crash"])
    np.testing.assert_allclose(np.asarray(obs), np.asarray(obs0))  # next episode's first observation
    assert float(info["terminal_obs"][0, 0]) > 350  # the leader's last position, past the line
    assert int(ws.episode_length) == 0 and float(ws.episode_return.sum()) == 0.0


def test_rollout_runs_many_envs_in_one_program():
    env = envs_jax.make("roundabout")
    out = jax.jit(envs_jax.rollout, static_argnums=(0, 2, 3))(env, KEY, 64, 25)
    assert out["reward"].shape == (25, 64, 2)
    finished = np.asarray(out["returned_episode"])
    assert finished.sum() >= 64  # every env finished at least one episode (<= 20 steps each)
    lengths = np.asarray(out["episode_length"])[finished]
    assert lengths.min() >= 1 and lengths.max() <= 20


def test_runs_under_x64(x64):
    env = envs_jax.make("merge")
    obs, st = env.reset(KEY)
    obs, st, r, c, done, info = env.step(KEY, st, np.array([3, 0]))
    assert st.x.dtype == jnp.float64 and obs.dtype == jnp.float64


def test_action_mode_is_an_option_of_make():
    env = envs_jax.make("racetrack", action_mode="both")
    assert env.action_shape == (2, 2)
    assert envs_jax.make("intersection").action_shape == (2, 1)
    config = {"action": {"type": "MultiAgentAction",
                         "action_config": {"type": "ContinuousAction", "longitudinal": True, "lateral": True}}}
    assert envs_jax.make("intersection", env_config=config).action_shape == (2, 2)
    with pytest.raises(ValueError, match="only applies to the continuous"):
        envs_jax.make("merge", action_mode="both")
    with pytest.raises(ValueError, match="unknown action_mode"):
        envs_jax.make("racetrack", action_mode="sideways")


def test_continuous_action_ranges_are_params():
    """a = +1 for one second at the default +-5 m/s^2 and at a user's +-3 m/s^2 (intersection)."""
    for limit, expected in ((None, 15.0), (3.0, 13.0)):
        overrides = {} if limit is None else {"acceleration_range": [-limit, limit]}
        env = envs_jax.make("intersection", start_noise=0.0, **overrides)
        _, st = env.reset(KEY)
        _, st, *_ = env.step(KEY, st, np.ones((2, 1), np.float32))
        np.testing.assert_allclose(np.asarray(st.speed), expected, atol=1e-4)


def test_auto_reset_records_offroad_and_distance_driven():
    """Racetrack with zero steering and zero acceleration: both cars drive straight at 10 m/s off the first curve
    (docs/scenarios.md, racetrack: off-road at step 21, x=119). The distance is the path length: 10 m/s x 0.2 s per
    step."""
    env = envs_jax.make("racetrack")
    w = envs_jax.AutoResetWrapper(env)
    params = env.default_params
    obs, st = w.reset(jax.random.PRNGKey(0), params)
    step = jax.jit(w.step)
    a = jnp.zeros(env.action_shape)
    for t in range(1, 60):
        x0, y0 = np.asarray(st.env_state.x), np.asarray(st.env_state.y)
        obs, st, r, c, done, info = step(jax.random.PRNGKey(t), st, a, params)
        if bool(done):
            break
        np.testing.assert_allclose(np.asarray(st.episode_distance) - np.asarray(info["episode_distance"]), 0)
        step_len = np.hypot(np.asarray(st.env_state.x) - x0, np.asarray(st.env_state.y) - y0)
        np.testing.assert_allclose(step_len, 2.0, rtol=1e-4)  # 10 m/s x 1/5 s, straight line
    assert bool(info["returned_episode"]) and bool(info["episode_offroad"])
    assert int(info["episode_length"]) == 21
    np.testing.assert_allclose(np.asarray(info["episode_distance"]), 2.0 * 21, rtol=1e-4)
    # a merge episode on the road all the time never flags off-road
    env = envs_jax.make("merge")
    out = jax.jit(envs_jax.rollout, static_argnums=(0, 2, 3))(env, jax.random.PRNGKey(1), 8, 60)
    ret = np.asarray(out["returned_episode"])
    assert ret.any()
    assert np.all(np.asarray(out["episode_distance"])[ret] > 0)
