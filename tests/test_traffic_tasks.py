"""merge-v0 and roundabout-v0 as traffic tasks: highway-env's config dicts, bad input, slot padding and the
placement rule of K > 1 controlled vehicles (the dynamics are checked in tests/test_parity_tasks.py)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from highway_env.envs.merge_env import MergeEnv
from highway_env.envs.roundabout_env import RoundaboutEnv

import envs_jax

TASKS = {"merge-v0": (MergeEnv, 9, 4), "roundabout-v0": (RoundaboutEnv, 8, 4)}  # class, max K, traffic vehicles


@functools.lru_cache(maxsize=None)
def full_env(name):
    """The task with the most controlled vehicles and its jitted batched reset (compiled once per task)."""
    env = envs_jax.make(name, controlled_vehicles=TASKS[name][1])
    return env, jax.jit(jax.vmap(lambda key, params: env.reset(key, params)[1], in_axes=(0, None)))


@pytest.mark.parametrize("name", list(TASKS))
def test_highway_env_config_accepted(name):
    """highway-env's own default config dict of the task, as it is, builds the task with its defaults."""
    cls, _, traffic = TASKS[name]
    env = envs_jax.make(name, cls.default_config())
    plain = envs_jax.make(name)
    assert env.num_slots == plain.num_slots == 1 + traffic
    assert env.obs_shape == plain.obs_shape == (1, 5, 5)
    assert jax.tree_util.tree_all(jax.tree_util.tree_map(lambda a, b: np.array_equal(a, b), env.default_params,
                                                         plain.default_params))
    multi = dict(cls.default_config(), controlled_vehicles=3,
                 observation={"type": "MultiAgentObservation",
                              "observation_config": cls.default_config()["observation"]},
                 action={"type": "MultiAgentAction", "action_config": cls.default_config()["action"]})
    env3 = envs_jax.make(name, multi)
    assert env3.controlled == (0, 1, 2) and env3.obs_shape == (3, 5, 5)


@pytest.mark.parametrize("name", list(TASKS))
def test_bad_config(name):
    _, max_k, traffic = TASKS[name]
    with pytest.raises(ValueError, match="lanes_count"):
        envs_jax.make(name, lanes_count=3)
    with pytest.raises(ValueError, match=rf"controlled_vehicles must be an integer in 1\.\.{max_k}, got {max_k + 1}"):
        envs_jax.make(name, controlled_vehicles=max_k + 1)
    with pytest.raises(ValueError, match=r"controlled_vehicles must be an integer in 1\.\."):
        envs_jax.make(name, controlled_vehicles=0)
    with pytest.raises(ValueError, match=rf"num_slots must be an integer >= {2 + traffic}, got {1 + traffic}"):
        envs_jax.make(name, controlled_vehicles=2, num_slots=1 + traffic)
    with pytest.raises(ValueError, match="neighbour_vehicles_connected_lanes"):
        envs_jax.make(name, neighbour_vehicles_connected_lanes=True)
    with pytest.raises(ValueError, match="other_vehicles_type"):
        envs_jax.make(name, other_vehicles_type="highway_env.vehicle.behavior.LinearVehicle")
    with pytest.raises(ValueError, match="collision_reward"):
        envs_jax.make(name, collision_reward="high")
    with pytest.raises(ValueError, match="action type"):
        envs_jax.make(name, action={"type": "ContinuousAction"})
    env = envs_jax.make(name, controlled_vehicles=2)
    with pytest.raises(ValueError, match=r"action must have shape \(2,\)"):
        env.step(jax.random.key(0), None, np.array([1]))  # checked before anything runs
    with pytest.raises(ValueError, match=r"in 0\.\.4"):
        env.step(jax.random.key(0), None, np.array([1, 5]))
    if name == "roundabout-v0":
        with pytest.raises(ValueError, match=r"incoming_vehicle_destination must be an integer in 0\.\.2"):
            envs_jax.make(name, incoming_vehicle_destination=3)
    else:
        with pytest.raises(ValueError, match="duration"):
            envs_jax.make(name, duration=-1)


@pytest.mark.slow
@pytest.mark.parametrize("name", list(TASKS))
def test_extra_slots_stay_empty(name):
    """Padding slots hold no vehicle: the vehicles, rewards and observations are those of the unpadded task."""
    k, traffic = 2, TASKS[name][2]
    a = envs_jax.make(name, controlled_vehicles=k)
    b = envs_jax.make(name, controlled_vehicles=k, num_slots=k + traffic + 3)
    (oa, sa), (ob, sb) = a.reset(jax.random.key(3)), b.reset(jax.random.key(3))
    n = k + traffic
    assert not np.asarray(sb.alive[n:]).any()
    for t in range(4):
        act = jnp.array([t % 5, 3])
        oa, sa, ra, ca, da, _ = a.step(jax.random.key(t), sa, act)
        ob, sb, rb, cb, db, _ = b.step(jax.random.key(t), sb, act)
        np.testing.assert_allclose(np.asarray(sb.x[:n]), np.asarray(sa.x), rtol=0, atol=1e-4)
        np.testing.assert_allclose(np.asarray(rb), np.asarray(ra), rtol=0, atol=1e-6)
        np.testing.assert_allclose(np.asarray(ob), np.asarray(oa), rtol=0, atol=1e-5)


@pytest.mark.parametrize("name", list(TASKS))
def test_placement_rule_keeps_vehicles_apart(name):
    """With the most controlled vehicles, every vehicle sharing a lane with an agent at reset is >= 15 m from it,
    over many reset draws (the traffic's positions are random)."""
    max_k, traffic = TASKS[name][1], TASKS[name][2]
    env, reset = full_env(name)
    states = reset(jax.random.split(jax.random.key(0), 256), env.default_params)
    x, y, lane = np.asarray(states.x), np.asarray(states.y), np.asarray(states.lane)
    dist = np.hypot(x[:, :, None] - x[:, None, :], y[:, :, None] - y[:, None, :])
    same = lane[:, :, None] == lane[:, None, :]
    agent = np.zeros(max_k + traffic, bool)
    agent[:max_k] = True
    pairs = same & (agent[:, None] | agent[None, :]) & ~np.eye(max_k + traffic, dtype=bool)
    assert dist[pairs].min() >= 15.0
    assert np.asarray(states.alive).all()


def test_roundabout_routes_and_destination():
    """Agents cross to the opposite exit; ``incoming_vehicle_destination`` fixes the incoming vehicle's exit."""
    env, reset = full_env("roundabout-v0")
    params = envs_jax.make("roundabout-v0", incoming_vehicle_destination=1).default_params
    assert params.incoming_vehicle_destination == 1
    params = env.default_params.replace(incoming_vehicle_destination=1)
    states = reset(jax.random.split(jax.random.key(0), 256), params)  # the batch of the placement test
    for b in range(8):
        last = lambda i: env.road.roads[int(states.route_roads[b, i, int(states.route_len[b, i]) - 1])][1]
        assert [last(i) for i in range(8)] == ["nxs", "exs", "sxs", "wxs"] * 2
        assert last(8) == "sxr"  # DESTINATIONS[1]


@pytest.mark.slow
def test_merge_reward_terms():
    """Per-agent reward parts: each agent's own lane-change action (highway-env counts the action, accepted or
    not) and the lane id of its own lane."""
    env, _ = full_env("merge-v0")
    _, st = env.reset(jax.random.key(0))
    # agent 0 LANE_RIGHT on the right-most lane (no change), agent 1 IDLE on the ramp, agent 2 LANE_LEFT
    # on the left-most lane (no change), the others IDLE
    _, st, _, _, _, info = env.step(jax.random.key(1), st, jnp.array([2, 1, 0, 1, 1, 1, 1, 1, 1]))
    parts = info["rewards"]
    np.testing.assert_array_equal(np.asarray(parts["lane_change_reward"]), [1, 0, 1, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(np.asarray(parts["right_lane_reward"])[:3], [1, 0, 0])  # a->b 1, ramp 0, a->b 0
