"""The authors' merge with K controlled agents on the traffic core (``envs_jax.make("merge-k")``; docs/scenarios.md).

Road, dynamics, actions, reward, cost and termination are those of the two-agent ``merge``
(:mod:`envs_jax.scenarios.merge`), generalised per agent: a two-lane highway a->b->c->d
joined by a ramp j->k->b whose merge lane (b->c, id 2) ends at a 2 x 2 m obstacle; MDP
meta-actions over the target speeds [20, 25, 30] m/s; 15 frames per decision; 20 s.

Placement (static): agents 0 and 1 start as the two-agent leader and follower, on the
highway's right lane at (70, 4) and on the ramp at (70, 14.5); agent k >= 2 starts
``AGENT_SPACING * (k // 2)`` metres behind them, on the highway for even k and on the
ramp for odd k (so K is 2 to 8 and the last two start at x = 10 m). Every agent starts at
25 m/s, heading 0, target speed 25 m/s. With ``other_vehicles=N`` (0 to 10), IDM/MOBIL
vehicles follow the agents in the slot list: vehicle i starts on the highway's left lane
(y = 0) at x = 110 - 20 i for i < 6, then on the right lane (y = 4) at x = 100 + 25 (i - 6),
at 25 m/s with target speed 25 m/s. No two vehicles overlap at reset.

Per agent k: reward ``speed_reward`` while its target-speed index is >= 1, plus
``collision_reward`` per step while crashed, plus a one-shot arrival bonus on first crossing
x > ``finish_x``; cost ``collision_cost * crashed``; terminated when crashed or past
``finish_x``. Arrival ranking (:func:`envs_jax.scenarios.arrival.ranked_arrival`): the first
agent to arrive gets ``first_arrival_reward``, every later one ``second_arrival_reward``;
agents arriving on the same step are ranked in agent order. ``info``: ``arrived [K]`` (latched),
``first_arrived`` (0 nobody yet, k + 1 when agent k was first), ``crash`` (any agent crashed) and the
traffic core's keys.

Observation ``[K, 4 n]`` (the authors' absolute, unnormalised ``x, y, vx, vy``), ``n =
observed_vehicles`` (default K): row k is agent k's own features, then those of the n - 1
nearest other vehicles (agents and traffic; Euclidean distance, nearest first, ties in slot
order), a zero block for each place left without a vehicle closer than 200 m
(:mod:`envs_jax.nearest_view`, shared with ``roundabout-k``). With K = 2 and
no traffic this is the two-agent ``[2, 8]`` view, and the whole environment reproduces
``envs_jax.make("merge")`` step for step.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import lanes as L
from envs_jax import nearest_view
from envs_jax.scenarios import config_values as CV
from envs_jax.scenarios.arrival import ArrivalBookkeeping, ArrivalState, ranked_arrival
from envs_jax.scenarios.merge import build_road
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams

NAME = "merge-k"
AGENT_SPACING = 20.0  # metres between successive agents on one lane, centre to centre (four car lengths)
HIGHWAY_Y, RAMP_Y = 4.0, 14.5  # the two-agent starts: right highway lane, ramp
START_X, START_SPEED = 70.0, 25.0
MIN_AGENTS, MAX_AGENTS = 2, 8
TRAFFIC_LEFT = 6  # other vehicles on the left lane before the right lane is used
MAX_OTHERS = 10
OBSTACLE_SIZE = 2.0


def agent_starts(k: int) -> np.ndarray:
    """``[k, 2]`` start positions ``(x, y)`` of the agents (host, float64)."""
    i = np.arange(k)
    return np.stack([START_X - AGENT_SPACING * (i // 2), np.where(i % 2 == 0, HIGHWAY_Y, RAMP_Y)], axis=-1)


def traffic_starts(n: int) -> np.ndarray:
    """``[n, 2]`` start positions ``(x, y)`` of the other vehicles (host, float64)."""
    i = np.arange(n)
    left = i < TRAFFIC_LEFT
    return np.stack([np.where(left, 110.0 - 20.0 * i, 100.0 + 25.0 * (i - TRAFFIC_LEFT)),
                     np.where(left, 0.0, HIGHWAY_Y)], axis=-1)


@struct.dataclass
class MergeAgentsParams(TrafficParams):
    duration: float = 20.0
    collision_cost: float = 5.0
    speed_reward: float = 2.0  # while target-speed index >= 1
    collision_reward: float = -5.0  # per step while crashed
    first_arrival_reward: float = 10.0
    second_arrival_reward: float = 5.0
    finish_x: float = 350.0


class MergeAgentsTask(Task):
    """The authors' merge with ``controlled_vehicles`` agents and ``other_vehicles`` IDM vehicles."""

    route_length = 1

    def __init__(self, controlled_vehicles: int, other_vehicles: int, observed_vehicles: int,
                 simulation_frequency: int, policy_frequency: int):
        self.name = NAME
        self.road, obstacle = build_road()
        self.obstacle = np.asarray(obstacle, np.float64)
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.num_agents = controlled_vehicles
        self.other_vehicles = other_vehicles
        self.observed_vehicles = observed_vehicles
        self.num_slots = controlled_vehicles + other_vehicles
        self.controlled = tuple(range(controlled_vehicles))
        # the agents hold slots 0..K-1, so slot order is the view's order (it decides ties)
        self.view_order = tuple(range(self.num_slots))
        self.vehicles_count = observed_vehicles
        self.starts = np.concatenate([agent_starts(controlled_vehicles), traffic_starts(other_vehicles)])

    def default_params(self) -> MergeAgentsParams:
        raise NotImplementedError  # built by make_merge_agents

    def initial_vehicles(self, key, params: MergeAgentsParams):
        """The static placement of the module docstring (``key`` is not used)."""
        del key
        dtype = L.float_dtype()
        n = self.num_slots
        return dict(x=jnp.asarray(self.starts[:, 0], dtype), y=jnp.asarray(self.starts[:, 1], dtype),
                    heading=jnp.zeros(n, dtype), speed=jnp.full(n, START_SPEED, dtype),
                    target_speed=jnp.full(n, START_SPEED, dtype), alive=jnp.ones(n, bool),
                    delta=jnp.full(n, params.idm.delta, dtype))

    def outcome(self, prev, state: ArrivalState, action, params: MergeAgentsParams):
        """The two-agent merge's outcome per agent; the new arrival flags go back through ``info``
        (:class:`MergeAgentsEnv` stores them in the state)."""
        idx = np.asarray(self.controlled)
        dtype = state.x.dtype
        crashed = state.crashed[idx]
        reward = params.speed_reward * (state.speed_index[idx] >= 1) + params.collision_reward * crashed
        beyond = state.x[idx] > params.finish_x
        bonus, arrived, first = ranked_arrival(beyond, state.arrived, state.first_arrived,
                                               params.first_arrival_reward, params.second_arrival_reward)
        reward = (reward + bonus).astype(dtype)
        cost = (params.collision_cost * crashed).astype(dtype)
        terminated = crashed | beyond
        info = {"crash": jnp.any(crashed), "arrived": arrived, "first_arrived": first}
        return reward, cost, terminated, info


class MergeAgentsEnv(ArrivalBookkeeping, nearest_view.NearestViewEnv, TrafficEnv):
    """:class:`TrafficEnv` with the authors' observation and the arrival flags kept in the state."""

    def __init__(self, task: MergeAgentsTask, default_params: MergeAgentsParams):
        super().__init__(task, default_params)
        self.use_nearest_view()


DEFAULTS = dict(controlled_vehicles=2, other_vehicles=0, observed_vehicles=None, simulation_frequency=15,
                policy_frequency=1, duration=20.0, collision_cost=5.0, speed_reward=2.0, collision_reward=-5.0,
                first_arrival_reward=10.0, second_arrival_reward=5.0, finish_x=350.0, target_speeds=[20, 25, 30],
                idm=None)


def make_merge_agents(name: str = NAME, env_config: dict | None = None, **overrides) -> MergeAgentsEnv:
    """``merge-k`` from keywords (or an ``env_config`` dict of the same keys).

    Keys: ``controlled_vehicles`` (K, 2..8), ``other_vehicles`` (IDM vehicles, 0..10),
    ``observed_vehicles`` (rows of each agent's view, 1..K + other_vehicles; default K),
    ``simulation_frequency``, ``policy_frequency``, ``duration`` [s], ``collision_cost``,
    the reward weights ``speed_reward``, ``collision_reward``, ``first_arrival_reward``,
    ``second_arrival_reward``, the arrival line ``finish_x`` [m], ``target_speeds`` and ``idm``
    (an IDMParams or a dict of its fields). Anything else, or a value out of range, raises
    ``ValueError`` naming it and what is allowed.
    """
    given = dict(env_config or {})
    given.update(overrides)
    unknown = sorted(k for k in given if k not in DEFAULTS)
    if unknown:
        raise ValueError(f"{name}: unknown key(s) {unknown}; allowed: {sorted(DEFAULTS)}")
    cfg = dict(DEFAULTS)
    cfg.update(given)
    k = cfg["controlled_vehicles"]
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not MIN_AGENTS <= k <= MAX_AGENTS:
        raise ValueError(f"{name}: controlled_vehicles must be an integer in {MIN_AGENTS}..{MAX_AGENTS} "
                         f"(agents on the highway and the ramp, {AGENT_SPACING:g} m apart), got {k!r}")
    k = int(k)
    others = CV.int_value(name, "other_vehicles", cfg["other_vehicles"], 0, MAX_OTHERS)
    seen = k if cfg["observed_vehicles"] is None else cfg["observed_vehicles"]
    seen = CV.int_value(name, "observed_vehicles", seen, 1, k + others)
    sim = CV.int_value(name, "simulation_frequency", cfg["simulation_frequency"], 1)
    pol = CV.int_value(name, "policy_frequency", cfg["policy_frequency"], 1, sim)
    num = lambda key: CV.number_value(name, key, cfg[key])
    ts = CV.meta_action_config(name, {"type": "DiscreteMetaAction", "target_speeds": cfg["target_speeds"]})
    task = MergeAgentsTask(k, others, seen, sim, pol)
    params = MergeAgentsParams(
        duration=CV.number_value(name, "duration", cfg["duration"], positive=True),
        collision_cost=CV.cost_value(name, "collision_cost", cfg["collision_cost"]),
        target_speeds=ts["target_speeds"], idm=CV.idm_params(name, cfg["idm"]),
        obstacles=np.array([[task.obstacle[0], task.obstacle[1], 0.0, OBSTACLE_SIZE, OBSTACLE_SIZE]]),
        speed_reward=num("speed_reward"), collision_reward=num("collision_reward"),
        first_arrival_reward=num("first_arrival_reward"), second_arrival_reward=num("second_arrival_reward"),
        finish_x=num("finish_x"))
    return MergeAgentsEnv(task, params)
