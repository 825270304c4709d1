"""racetrack-v0 (traffic task): the spawn rule against highway-env's own ``_make_vehicles``, the occupancy
grid's exact multiply-add, config handling (highway-env's own dicts accepted, bad input named)."""

from __future__ import annotations

from fractions import Fraction

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from highway_env.envs.racetrack_env import RacetrackEnv

import envs_jax
from envs_jax.occupancy_grid import fma


class DrawsRng:
    """The random source of ``RacetrackEnv._make_vehicles`` answering with the JAX draws, in call order."""

    def __init__(self, draws, graph, k, others):
        self.d = {key: np.asarray(v) for key, v in draws.items()}
        self.nodes = list(graph)
        self.calls = []
        self.k, self.others = k, others
        self.slot = 0  # vehicle the next lane / position draw belongs to
        self.extra_asked = False

    def integers(self, n):
        if self.slot >= self.k + 1 and not self.extra_asked:  # rng.integers(other_vehicles)
            assert n == self.others
            self.extra_asked = True
            return int(self.d["extra"])
        assert n == 2
        return int(self.d["lane_id"][self.slot])

    def choice(self, options):
        options = list(options)
        if options == self.nodes:
            return options[int(self.d["road"][self.slot])]
        assert len(options) == 1  # each racetrack node has one successor
        return options[0]

    def uniform(self, low=0.0, high=1.0):
        i = self.slot
        if (low, high) == (0.0, 3.0):  # the IDM vehicle's speed: the last draw of a vehicle
            self.slot += 1
            return float(self.d["speed_u"][i])
        if (low, high) == (20, 50):  # an agent's position: its last draw
            self.slot += 1
            return float(20.0 + 30.0 * self.d["frac"][i])
        return float(self.d["frac"][i] * high)


@pytest.mark.parametrize("k,others", [(3, 6), (2, 0)])
def test_spawn_rule_matches_highway_env(k, others, x64):
    """JAX ``place(draws)`` = highway-env's ``_make_vehicles`` fed the same draws (lanes, positions, the
    front vehicle on (b, c) with the last agent's lane id, the 20 m rejection in list order)."""
    env = envs_jax.make("racetrack-v0", controlled_vehicles=k, other_vehicles=others)
    task, params = env.task, env.default_params
    he = RacetrackEnv(config={"controlled_vehicles": k, "other_vehicles": others})
    he.reset(seed=0)
    kept = 0
    draw, place = jax.jit(task.draws), jax.jit(task.place)
    for seed in range(40):
        draws = jax.device_get(draw(jax.random.key(seed), params))
        init = jax.device_get(place(draws, params))
        he.road.vehicles = []
        he._np_random = DrawsRng(draws, he.road.network.graph, k, others)
        he._make_vehicles()
        alive = np.asarray(init["alive"])
        vehicles = he.road.vehicles
        assert alive.sum() == len(vehicles)
        kept += len(vehicles)
        for key, get in (("x", lambda v: v.position[0]), ("y", lambda v: v.position[1]),
                         ("heading", lambda v: v.heading), ("speed", lambda v: v.speed)):
            np.testing.assert_allclose(np.asarray(init[key])[alive], [get(v) for v in vehicles], rtol=0, atol=1e-9,
                                       err_msg=key)
        assert [type(v).__name__ for v in vehicles] == ["Vehicle"] * k + ["IDMVehicle"] * (len(vehicles) - k)
    assert kept < 40 * (k + others) or others <= 1  # the 20 m rule dropped some candidates


def test_fma_is_correctly_rounded(x64):
    rng = np.random.default_rng(0)
    a, b, c = rng.normal(size=(3, 2000)) * np.array([[1.0], [50.0], [1e-3]])
    got = np.asarray(jax.jit(fma)(a, b, c))
    exact = [float(Fraction(x) * Fraction(y) + Fraction(z)) for x, y, z in zip(a, b, c)]
    np.testing.assert_array_equal(got, exact)


def test_highway_env_default_config_accepted():
    env = envs_jax.make("racetrack-v0", env_config=RacetrackEnv.default_config())
    assert env.action_shape == (1, 1) and env.obs_shape == (1, 2, 12, 12) and env.num_slots == 2
    assert env.task.max_steps == 1501  # highway-env's float clock: 1500 steps of 0.2 s stay below 300 s
    multi = envs_jax.make("racetrack-v0", controlled_vehicles=3, other_vehicles=4,
                          action={"type": "MultiAgentAction", "action_config": {"type": "ContinuousAction",
                                                                                "longitudinal": True}},
                          observation={"type": "MultiAgentObservation",
                                       "observation_config": {"type": "Kinematics", "vehicles_count": 4}})
    assert multi.action_shape == (3, 2) and multi.obs_shape == (3, 4, 5) and multi.num_slots == 7


@pytest.mark.parametrize("kwargs,needle", [
    (dict(lanes_count=3), "unknown config key(s) ['lanes_count']"),
    (dict(controlled_vehicles=0), "controlled_vehicles must be an integer >= 1"),
    (dict(other_vehicles=-1), "other_vehicles must be an integer >= 0"),
    (dict(other_vehicles=4, num_slots=3), "num_slots must be an integer >= 5"),
    (dict(observation={"type": "OccupancyGrid", "absolute": True}), "absolute=True is not supported"),
    (dict(observation={"type": "OccupancyGrid", "features": ["presence", "speed"]}), "unknown OccupancyGrid feature"),
    (dict(observation={"type": "GrayscaleObservation"}), "observation type must be 'OccupancyGrid' or 'Kinematics'"),
    (dict(action={"type": "DiscreteMetaAction"}), "action type must be 'ContinuousAction'"),
    (dict(action={"type": "ContinuousAction", "dynamical": True}), "dynamical=True"),
    (dict(neighbour_vehicles_connected_lanes=True), "racetrack-v1"),
    (dict(collision_reward=1), "collision_reward must differ from 1"),
    (dict(offroad_cost=-1.0), "offroad_cost is a cost"),
])
def test_bad_config_named(kwargs, needle):
    with pytest.raises(ValueError) as err:
        envs_jax.make("racetrack-v0", **kwargs)
    assert needle in str(err.value)


def test_bad_action_named():
    env = envs_jax.make("racetrack-v0", controlled_vehicles=2)
    with pytest.raises(ValueError, match=r"action must have shape \(2, 1\)"):
        env.check_action(jnp.zeros((2,)))
    with pytest.raises(ValueError, match="must be finite"):
        env.check_action(jnp.array([[0.0], [jnp.nan]]))
    np.testing.assert_array_equal(env.check_action(np.array([[2.0], [-0.5]])), [[1.0], [-0.5]])
