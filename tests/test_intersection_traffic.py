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
    from highway_env.vehicle.behavior import IDMVehicle

    from tests.intersection_oracle import IDM_ATTRS
    from tests.traffic_oracle import lane_numbers

    saved = {a: getattr(IDMVehicle, a) for a in IDM_ATTRS}
    try:  # the env overwrites IDMVehicle's class constants at reset
        he = IntersectionEnv()
        he.reset(seed=0)
    finally:
        for a, v in saved.items():
            setattr(IDMVehicle, a, v)
    net = he.road.network
    env = envs_jax.make("intersection-v0")
    numbers = lane_numbers(net)
    prio = lane_priorities(env.road)
    for (f, t, i), g in numbers.items():
        assert prio[g] == net.get_lane((f, t, i)).priority
    for a in range(4):
        for d in range(4):
            assert shortest_path(env.road.roads, f"ir{a}", f"o{d}") == net.shortest_path(f"ir{a}", f"o{d}")
