"""intersection-v0 with traffic: configuration checks and closed-form properties (the parity suite is
tests/test_parity_intersection.py)."""

from __future__ import annotations

import numpy as np
import pytest

import envs_jax
from envs_jax.scenarios.intersection_traffic import default_num_slots, lane_priorities, shortest_path


def test_defaults_and_bad_input():
    env = envs_jax.make("intersection-v0")
    assert env.num_agents == 1 and env.num_slots == default_num_slots(1, 10, 13, 1) == 24
    assert env.obs_shape == (1, 15, 7)
    assert envs_jax.make("intersection-multi-agent-v0").num_agents == 2
    for kw, word in [({"destination": "o7"}, "destination"), ({"spawn_probability": 1.5}, "spawn_probability"),
                     ({"num_slots": 1}, "num_slots"), ({"action": {"type": "DiscreteMetaAction", "lateral": True}},
                                                       "lateral"), ({"foo": 1}, "unknown")]:
        with pytest.raises(ValueError, match=word):
            envs_jax.make("intersection-v0", **kw)
    with pytest.raises(ValueError, match="0..2"):
        env.check_action(np.array([3]))


def test_priorities_and_routes_match_highway_env():
    """Lane priorities and planned routes against highway-env's own road and shortest_path."""
    from highway_env.envs.intersection_env import IntersectionEnv

    from tests.intersection_oracle import idm_constants_kept
    from tests.traffic_oracle import lane_numbers

    with idm_constants_kept():  # the env overwrites IDMVehicle's class constants at reset
        he = IntersectionEnv()
        he.reset(seed=0)
    net = he.road.network
    env = envs_jax.make("intersection-v0")
    numbers = lane_numbers(net)
    prio = lane_priorities(env.road)
    for (f, t, i), g in numbers.items():
        assert prio[g] == net.get_lane((f, t, i)).priority
    for a in range(4):
        for d in range(4):
            assert shortest_path(env.road.roads, f"ir{a}", f"o{d}") == net.shortest_path(f"ir{a}", f"o{d}")


def test_v1_defaults_and_bad_input():
    """intersection-v1: ContinuousIntersectionEnv's default config (highway-env's, read from it), K agents,
    and the checks of its ContinuousAction section."""
    from highway_env.envs.intersection_env import ContinuousIntersectionEnv

    cfg = ContinuousIntersectionEnv.default_config()
    env = envs_jax.make("intersection-v1")
    p = env.default_params
    assert env.num_agents == 1 and env.action_shape == (1, 2) and not env.discrete
    assert env.obs_shape == (1, cfg["observation"]["vehicles_count"], len(cfg["observation"]["features"]))
    assert env.obs_config.features == tuple(cfg["observation"]["features"])
    assert tuple(p.steering_range) == tuple(cfg["action"]["steering_range"])
    assert tuple(p.acceleration_range) == (-5.0, 5.0) and cfg["action"]["dynamical"] is True
    assert (p.duration, p.collision_reward, p.arrived_reward, p.spawn_probability) == (
        cfg["duration"], cfg["collision_reward"], cfg["arrived_reward"], cfg["spawn_probability"])
    assert env.num_slots == default_num_slots(1, 10, 13, 1)
    four = envs_jax.make("intersection-v1", controlled_vehicles=4)
    assert four.action_shape == (4, 2) and four.obs_shape == (4, 5, 8)
    lon = envs_jax.make("intersection-v1", action={"type": "ContinuousAction", "lateral": False, "dynamical": True})
    assert lon.action_shape == (1, 1)
    for kw, word in [({"action": {"type": "ContinuousAction"}}, "dynamical=False"),
                     ({"action": {"type": "DiscreteMetaAction"}}, "ContinuousAction"),
                     ({"action": dict(type="ContinuousAction", dynamical=True, steering_range=[1, -1])},
                      "steering_range"),
                     ({"action": dict(type="ContinuousAction", dynamical=True, speed_range=[0, 9])}, "speed_range"),
                     ({"destination": "o9"}, "destination"), ({"bar": 1}, "unknown")]:
        with pytest.raises(ValueError, match=word):
            envs_jax.make("intersection-v1", **kw)
    with pytest.raises(ValueError, match="shape"):
        env.check_action(np.zeros((1, 3)))
    with pytest.raises(ValueError, match="finite"):
        env.check_action(np.array([[np.nan, 0.0]]))
