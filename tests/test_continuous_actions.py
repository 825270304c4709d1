"""The continuous action model of intersection and racetrack: action modes, validation, robustness.

* ``longitudinal`` / ``lateral`` / ``both`` are options of one action model (``action_mode``), for
  either scenario;
* eager use: NaN, +-inf, a wrong shape or a non-float dtype raise ``ValueError``;
* inside ``jit``: NaN is read as 0 and everything is clipped to [-1, 1] (documented policy);
* 10^6 random steps per scenario (4096 auto-resetting envs x 250 steps, one jit) with actions at
  and beyond the bounds, including NaN and +-inf, never produce a non-finite state.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from envs_jax import vehicle as V
from envs_jax.scenarios.continuous import action_flags, action_mode, with_action_mode
from envs_jax.wrappers import AutoResetWrapper

SCENARIOS = ["intersection", "racetrack"]
MODES = ["longitudinal", "lateral", "both"]


def make(scenario, mode=None):
    env = envs_jax.make(scenario)
    return env if mode is None else with_action_mode(env, mode)


def test_default_modes():
    assert make("intersection").scenario.action_mode == "longitudinal"
    assert make("racetrack").scenario.action_mode == "lateral"
    for scenario in SCENARIOS:
        assert make(scenario).action_shape == (2, 1)
        assert make(scenario, "both").action_shape == (2, 2)
    assert action_flags("both") == (True, True) and action_mode(False, True) == "lateral"
    with pytest.raises(ValueError, match="action_mode"):
        make("racetrack", "steering")
    with pytest.raises(ValueError, match="continuous"):
        with_action_mode(envs_jax.make("merge"), "both")
    env = make("intersection")
    assert with_action_mode(env, "longitudinal") is env


_OBS = {"type": "MultiAgentObservation",
        "observation_config": {"type": "Kinematics", "flatten": True, "absolute": True, "see_behind": True,
                               "normalize": False, "features": ["x", "y", "vx", "vy"], "vehicles_count": 2}}
AUTHORS_CONFIG = {  # the keys of the authors' env_config.json files (docs/scenarios.md)
    "intersection": {
        "simulation_frequency": 15, "policy_frequency": 1, "duration": 20, "controlled_vehicles": 2,
        "initial_vehicle_count": 0, "spawn_probability": 0, "destination": "o1", "offroad_terminal": True,
        "scaling": 7.15, "screen_width": 600, "screen_height": 600, "observation": _OBS,
        "action": {"type": "MultiAgentAction",
                   "action_config": {"type": "ContinuousAction", "longitudinal": True, "lateral": False}},
        "arrived_reward": 10, "collision_reward": -10, "high_speed_reward": 0, "on_road_reward": 0,
        "first_arrive_reward": 20, "second_arrive_reward": 10},
    "racetrack": {
        "simulation_frequency": 15, "policy_frequency": 5, "duration": 40, "controlled_vehicles": 2,
        "collision_reward": -1, "lane_centering_cost": 4, "lane_centering_reward": 1, "action_reward": -0.3,
        "screen_width": 600, "screen_height": 600, "observation": _OBS,
        "action": {"type": "MultiAgentAction",
                   "action_config": {"type": "ContinuousAction", "longitudinal": False, "lateral": True,
                                     "target_speeds": [0, 5, 10]}}},
}


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_authors_env_config(scenario):
    """The authors' env_config.json gives the default environment; the unused reward keys are inert."""
    env = envs_jax.make(scenario, env_config=AUTHORS_CONFIG[scenario])
    default = envs_jax.make(scenario)
    assert (env.frames, env.action_shape) == (default.frames, default.action_shape)
    for a, b in zip(jax.tree_util.tree_leaves(env.default_params), jax.tree_util.tree_leaves(default.default_params)):
        np.testing.assert_array_equal(np.asarray(a, float), np.asarray(b, float))
    if scenario == "intersection":  # collision_reward: -10 is never read by the multi-agent step
        assert env.default_params.collision_reward == -5.0
    assert (env.frames, default.default_params.duration) == ({"intersection": 15, "racetrack": 3}[scenario],
                                                            {"intersection": 20.0, "racetrack": 40.0}[scenario])


@pytest.mark.parametrize("scenario", SCENARIOS)
@pytest.mark.parametrize("mode", MODES)
def test_action_mode_semantics(scenario, mode):
    """Acceleration only / steering only / both, mapped as highway-env's lmap([-1, 1] -> range)."""
    env = make(scenario, mode)
    lon, lat = action_flags(mode)
    d = int(lon) + int(lat)
    _, st0 = env.reset(jax.random.key(0))
    step = jax.jit(env.step)
    action = np.full((2, d), 0.5, np.float32)
    _, st, *_ = step(jax.random.key(0), st0, action)
    np.testing.assert_allclose(np.asarray(st.acceleration), 2.5 if lon else 0.0, rtol=1e-6)
    np.testing.assert_allclose(np.asarray(st.steering), np.pi / 8 if lat else 0.0, rtol=1e-6)
    dt = 1.0 / env.policy_frequency
    np.testing.assert_allclose(np.asarray(st.speed), 10.0 + (2.5 * dt if lon else 0.0), rtol=1e-5)
    turned = np.abs(np.asarray(st.heading - st0.heading)) > 1e-3
    assert turned.all() == lat and turned.any() == lat
    if d == 1:  # shape [2] is accepted for 1-D actions
        _, st_flat, *_ = step(jax.random.key(0), st0, action[:, 0])
        np.testing.assert_array_equal(np.asarray(st_flat.x), np.asarray(st.x))


@pytest.mark.parametrize("scenario", SCENARIOS)
@pytest.mark.parametrize("mode", [None, "both"])
def test_eager_validation(scenario, mode):
    """Non-finite values, wrong shapes and non-float dtypes raise a clear ValueError in eager use."""
    env = make(scenario, mode)
    d = env.action_dim
    _, st = env.reset(jax.random.key(0))
    good = np.zeros((2, d), np.float32)
    env.step(jax.random.key(0), st, good)
    for bad_value in (np.nan, np.inf, -np.inf):
        bad = good.copy()
        bad[1, d - 1] = bad_value
        with pytest.raises(ValueError, match="finite"):
            env.step(jax.random.key(0), st, bad)
        with pytest.raises(ValueError, match="finite"):
            env.step(jax.random.key(0), st, jnp.asarray(bad))
    shapes = [(), (1,), (3,), (2, 3), (1, d), (4, 2, d), (2, 2 if d == 1 else 1)]
    if d == 2:
        shapes.append((2,))
    for shape in shapes:
        with pytest.raises(ValueError, match="shape"):
            env.step(jax.random.key(0), st, np.zeros(shape, np.float32))
    with pytest.raises(ValueError, match="float"):
        env.step(jax.random.key(0), st, np.zeros((2, d), np.int32))


@pytest.mark.parametrize("scenario", SCENARIOS)
@pytest.mark.parametrize("mode", [None, "both"])
def test_jit_policy_nan_to_zero_and_clip(scenario, mode):
    """Under jit, NaN acts as 0 and values beyond [-1, 1] (incl. +-inf) as the bound."""
    env = make(scenario, mode)
    d = env.action_dim
    _, st = env.reset(jax.random.key(0))
    step = jax.jit(env.step)
    raw = np.array([[np.nan, -np.inf], [np.inf, 1e30], [-7.0, np.nan], [1.0 + 1e-6, -0.25]], np.float32)
    clean = np.array([[0.0, -1.0], [1.0, 1.0], [-1.0, 0.0], [1.0, -0.25]], np.float32)
    for k in range(0, len(raw), 2):
        a, b = raw[k:k + 2, :d], clean[k:k + 2, :d]
        out_raw = step(jax.random.key(0), st, a)
        out_clean = step(jax.random.key(0), st, b)
        for x, y in zip(jax.tree_util.tree_leaves(out_raw), jax.tree_util.tree_leaves(out_clean)):
            np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
        assert all(bool(jnp.all(jnp.isfinite(x))) for x in jax.tree_util.tree_leaves(out_raw)
                   if jnp.issubdtype(x.dtype, jnp.floating))


# Action values at and beyond the bounds, mixed with uniform draws in [-1.5, 1.5].
SPECIAL = np.array([np.nan, np.inf, -np.inf, 1.0, -1.0, 0.0, -0.0, 1e30, -1e30, 1.0000001, -1.0000001,
                    3.0, -3.0, 1e-40, np.finfo(np.float32).max, -np.finfo(np.float32).max], np.float32)


def adversarial_actions(key, shape):
    k1, k2, k3 = jax.random.split(key, 3)
    uniform = jax.random.uniform(k1, shape, minval=-1.5, maxval=1.5)
    special = jnp.asarray(SPECIAL)[jax.random.randint(k2, shape, 0, len(SPECIAL))]
    return jnp.where(jax.random.uniform(k3, shape) < 0.3, special, uniform)


def _float_leaves(tree):
    return [x for x in jax.tree_util.tree_leaves(tree) if jnp.issubdtype(x.dtype, jnp.floating)]


def stress(env, num_envs, num_steps, key):
    """One jitted program: auto-resetting envs under adversarial actions; returns finiteness and ranges."""
    wrapped = AutoResetWrapper(env)
    params = env.default_params

    def run(key):
        key, k0 = jax.random.split(key)
        obs, state = jax.vmap(wrapped.reset, in_axes=(0, None))(jax.random.split(k0, num_envs), params)

        def body(carry, _):
            obs, state, key, stats = carry
            key, ka, ks = jax.random.split(key, 3)
            action = adversarial_actions(ka, (num_envs,) + env.action_shape)
            obs, state, reward, cost, done, info = jax.vmap(wrapped.step, in_axes=(0, 0, 0, None))(
                jax.random.split(ks, num_envs), state, action, params)
            finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(x)) for x in _float_leaves((obs, state, reward, cost))]))
            s = state.env_state
            stats = dict(finite=stats["finite"] & finite,
                         max_speed=jnp.maximum(stats["max_speed"], jnp.max(jnp.abs(s.speed))),
                         max_pos=jnp.maximum(stats["max_pos"], jnp.max(jnp.maximum(jnp.abs(s.x), jnp.abs(s.y)))),
                         min_reward=jnp.minimum(stats["min_reward"], jnp.min(reward)),
                         max_reward=jnp.maximum(stats["max_reward"], jnp.max(reward)),
                         episodes=stats["episodes"] + jnp.sum(done),
                         nonfinite_actions=stats["nonfinite_actions"] + jnp.sum(~jnp.isfinite(action)))
            return (obs, state, key, stats), None

        zero = jnp.zeros((), obs.dtype)
        stats = dict(finite=jnp.all(jnp.isfinite(obs)), max_speed=zero, max_pos=zero, min_reward=zero + jnp.inf,
                     max_reward=zero - jnp.inf, episodes=jnp.zeros((), jnp.int32),
                     nonfinite_actions=jnp.zeros((), jnp.int32))
        (_, state, _, stats), _ = jax.lax.scan(body, (obs, state, key, stats), None, length=num_steps)
        return stats

    return jax.device_get(jax.jit(run)(key))


REWARD_RANGE = {"intersection": (-5.0, 7.0), "racetrack": (-0.15, 1.0)}


@pytest.mark.parametrize("scenario", [pytest.param("intersection", marks=pytest.mark.slow), "racetrack"])  # one default
def test_no_nan_over_a_million_random_steps(scenario):
    """4096 envs x 250 steps = 1,024,000 steps with NaN / inf / out-of-range actions: the state stays finite."""
    env = make(scenario)
    t0 = time.time()
    stats = stress(env, 4096, 250, jax.random.key(7))
    elapsed = time.time() - t0
    print(f"\n{scenario}: 1,024,000 steps in {elapsed:.1f} s (incl. compile), {int(stats['episodes'])} episodes, "
          f"{int(stats['nonfinite_actions'])} NaN/inf action entries, max |speed| {float(stats['max_speed']):.3f}, "
          f"rewards in [{float(stats['min_reward']):.3f}, {float(stats['max_reward']):.3f}]")
    assert bool(stats["finite"])
    assert int(stats["nonfinite_actions"]) > 100_000 and int(stats["episodes"]) > 4096
    # the +-40 m/s guard overshoots by at most one frame of 5 m/s^2
    assert float(stats["max_speed"]) <= V.MAX_SPEED + 5.0 / env.simulation_frequency + 1e-3
    lo, hi = REWARD_RANGE[scenario]
    assert lo - 1e-5 <= float(stats["min_reward"]) and float(stats["max_reward"]) <= hi + 1e-5


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_no_nan_two_dimensional_actions(scenario):
    """The same in the 2-D mode (throttle and steering), on a smaller batch."""
    stats = stress(make(scenario, "both"), 512, 100, jax.random.key(8))
    assert bool(stats["finite"]) and int(stats["nonfinite_actions"]) > 1000
    assert float(stats["max_speed"]) <= V.MAX_SPEED + 5.0 / 15 + 1e-3
