"""``merge-cavs-v0``: the multi-agent on-ramp merge of MARL_CAVs (Chen et al., IEEE T-ITS 2023; docs/scenarios.md).

Road (MARL_CAVs' ``_make_road``, sections ``ENDS`` = 220, 100, 100, 100 m): a one-lane main road a->b->c->d on
y = 0 and a ramp j->k (y = 10.5) -> k->b (a sine lane) whose merge lane b->c 1 (y = 4, x 320..420) ends at a
2 x 2 m obstacle at (420, 4); the ramp lanes are forbidden to lane changes into them.

Vehicles (``_make_vehicles``), in list order: the controlled vehicles (CAVs), those on the main road first, then the
human-driven IDM vehicles (HDVs), main road first. Per episode ``traffic_density`` draws the counts: 1: 1-3 CAVs and
1-3 HDVs, 2: 2-4 and 2-4, 3: 4-6 and 3-5 (uniform). ``n // 2`` of n vehicles of a kind start on the main road
a->b, the others on the ramp j->k, at spawn points drawn without replacement from 10, 50, ..., 210 m (main) and
5, 45, ..., 205 m (ramp), CAVs first, each + U(-1.5, 1.5) m, at U(25, 27) m/s. An IDM driver's target speed is its
initial speed; a CAV is an MDP vehicle over the target speeds 10, 15, 20, 25, 30 m/s.

Fixed shapes: K = the density's largest CAV count agent slots, then its largest HDV count. Agent k is present
when k < the episode's CAV count; ``info["alive"] [K]`` (and :func:`agents_alive` of a state) says which. An
absent agent's slot holds no vehicle (no collisions, in no observation), its observation is zeros, its reward
and cost are 0 and it is terminated from the start.

Reward of a present agent (``_agent_reward``): ``-COLLISION_REWARD * crashed + HIGH_SPEED_REWARD *
clip(lmap(speed, reward_speed_range, [0, 1]), 0, 1) + MERGING_LANE_COST * m + HEADWAY_COST * min(0, h)`` with
``m = -exp(-(x - 420)^2 / (10 * 100))`` on the merge lane b->c 1 (else 0) and ``h = log(headway / (HEADWAY_TIME
* speed))`` for speed > 0 (else 0); the headway is the smallest x-distance to a vehicle ahead on the agent's lane
or, off the merge lane, on its next lane (``RoadNetwork.next_lane``), at most 60 m. ``info["mean_reward"]`` is
MARL_CAVs' cooperative reward, the mean over present agents. Cost ``collision_cost * crashed``. The episode ends
when any present agent crashes (MARL_CAVs' ``_is_terminal``): every agent is then terminated; the time limit
(``duration``, 20 s at 5 decisions per second) truncates. ``info["average_speed"]``: the mean speed of the present
agents (MARL_CAVs' metric).
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from envs_jax import kinematic_obs
from envs_jax import lanes as L
from envs_jax import vehicle as Veh
from envs_jax.idm import IDMParams
from envs_jax.road import RoadNetwork
from envs_jax.scenarios import config_values as CV
from envs_jax.traffic_env import Task, TrafficEnv, TrafficParams

C, S, N = L.LINE_CONTINUOUS_LINE, L.LINE_STRIPED, L.LINE_NONE

NAME = "merge-cavs-v0"
ENDS = (220.0, 100.0, 100.0, 100.0)  # before, converging, merge, after [m]
MERGE_END = sum(ENDS[:3])  # x where the merge lane ends
RAMP_Y = 6.5 + 4.0
AMPLITUDE = 3.25
OBSTACLE_SIZE = 2.0
# MARL_CAVs' drivers take their target speed as it is; every lane's limit lies above all target speeds so that
# highway-env's clip of the IDM target speed to the lane's limit never acts.
SPEED_LIMIT = Veh.MAX_SPEED
MAIN_SPAWNS = (10.0, 50.0, 90.0, 130.0, 170.0, 210.0)
RAMP_SPAWNS = (5.0, 45.0, 85.0, 125.0, 165.0, 205.0)
SPEED_RANGE = (25.0, 27.0)
POSITION_NOISE = 1.5
HEADWAY_CAP = 60.0
# traffic_density -> (fewest CAVs, most CAVs, fewest HDVs, most HDVs)
DENSITIES = {1: (1, 3, 1, 3), 2: (2, 4, 2, 4), 3: (4, 6, 3, 5)}
DENSITY_NAMES = {"easy": 1, "medium": 2, "hard": 3}
# MARL_CAVs' IDMVehicle constants that differ from highway-env's
CAVS_IDM = IDMParams(lane_change_min_acc_gain=0.1, lane_change_max_braking_imposed=9.0)
# MARL_CAVs' KinematicObservation: vehicles behind seen, no obstacles, its fixed ranges (5 and 1.5 times its top
# speed of 30 m/s, y +-12 m), not clipped
OBSERVATION = {"type": "Kinematics", "see_behind": True, "clip": False, "include_obstacles": False,
               "features_range": {"x": [-150.0, 150.0], "y": [-12.0, 12.0], "vx": [-45.0, 45.0], "vy": [-45.0, 45.0]}}


@struct.dataclass
class MergeCavsParams(TrafficParams):
    collision_reward: float = 200.0  # COLLISION_REWARD, subtracted while crashed
    high_speed_reward: float = 1.0  # HIGH_SPEED_REWARD
    headway_cost: float = 4.0  # HEADWAY_COST
    headway_time: float = 1.2  # HEADWAY_TIME [s]
    merging_lane_cost: float = 4.0  # MERGING_LANE_COST
    reward_speed_range: Any = (10.0, 30.0)


DEFAULTS = dict(simulation_frequency=15, policy_frequency=5, duration=20, reward_speed_range=[10, 30],
                COLLISION_REWARD=200, HIGH_SPEED_REWARD=1, HEADWAY_COST=4, HEADWAY_TIME=1.2, MERGING_LANE_COST=4,
                traffic_density=1, safety_guarantee=False, action_masking=False)
OWN_KEYS = ("num_slots", "collision_cost", "idm")


def build_road():
    """MARL_CAVs' ``_make_road`` (same lanes, same insertion order); returns the road and the obstacle position."""
    net = RoadNetwork()
    e0, e1, e2, e3 = ENDS
    lim = dict(speed_limit=SPEED_LIMIT)
    net.add_lane("a", "b", L.straight([0, 0], [e0 + e1, 0], line_types=[C, C], **lim))
    net.add_lane("b", "c", L.straight([e0 + e1, 0], [e0 + e1 + e2, 0], line_types=[C, S], **lim))
    net.add_lane("c", "d", L.straight([e0 + e1 + e2, 0], [e0 + e1 + e2 + e3, 0], line_types=[C, C], **lim))
    net.add_lane("j", "k", L.straight([0, RAMP_Y], [e0, RAMP_Y], line_types=[C, C], forbidden=True, **lim))
    # SineLane(ljk.position(e0, -A), ljk.position(e0 + e1, -A), A, 2 pi / (2 e1), pi / 2)
    kb_start = np.array([e0, RAMP_Y - AMPLITUDE])
    kb_end = np.array([e0 + e1, RAMP_Y - AMPLITUDE])
    pulsation = 2 * np.pi / (2 * e1)
    net.add_lane("k", "b", L.sine(kb_start, kb_end, AMPLITUDE, pulsation, np.pi / 2, line_types=[C, C],
                                  forbidden=True, **lim))
    # lbc starts at lkb.position(e1, 0), computed as highway-env does (start + s dir + A sin(w s + phase) lat)
    direction = (kb_end - kb_start) / np.linalg.norm(kb_end - kb_start)
    lateral = np.array([-direction[1], direction[0]])
    lbc_start = kb_start + e1 * direction + AMPLITUDE * np.sin(pulsation * e1 + np.pi / 2) * lateral
    net.add_lane("b", "c", L.straight(lbc_start, lbc_start + [e2, 0], line_types=[N, C], forbidden=True, **lim))
    return net.freeze(), lbc_start + [e2, 0]


def density_of(name: str, value) -> int:
    """``traffic_density`` as 1, 2 or 3 (also ``"easy"``, ``"medium"``, ``"hard"``); ``ValueError`` otherwise."""
    if isinstance(value, str) and value in DENSITY_NAMES:
        return DENSITY_NAMES[value]
    if not isinstance(value, bool) and isinstance(value, (int, np.integer)) and int(value) in DENSITIES:
        return int(value)
    raise ValueError(f"{name}: traffic_density must be 1, 2 or 3 (or 'easy', 'medium', 'hard'), got {value!r}")


def agents_alive(env: TrafficEnv, state) -> jax.Array:
    """``[K]`` bool: which agents hold a vehicle this episode (``[..., K]`` under vmap of the state)."""
    return state.alive[..., np.asarray(env.controlled)]


class MergeCavsTask(Task):
    """MARL_CAVs' merge at one traffic density: ``num_agents`` CAV slots, then the HDV slots."""

    route_length = 1

    def __init__(self, density: int, num_slots: int | None, simulation_frequency: int, policy_frequency: int,
                 obs_config: kinematic_obs.KinematicsConfig):
        self.name = NAME
        self.density = density
        self.cav_range = DENSITIES[density][:2]
        self.hdv_range = DENSITIES[density][2:]
        self.road, obstacle = build_road()
        self.obstacle = np.asarray(obstacle, np.float64)
        self.simulation_frequency = simulation_frequency
        self.policy_frequency = policy_frequency
        self.obs_config = obs_config
        self.num_agents = self.cav_range[1]
        self.num_hdv_slots = self.hdv_range[1]
        self.num_vehicles = self.num_agents + self.num_hdv_slots
        self.num_slots = self.num_vehicles if num_slots is None else num_slots
        self.controlled = tuple(range(self.num_agents))
        # every vehicle starts on a one-lane road (a->b or j->k): highway-env's y range of 1 lane
        self.obs_range_lanes = (1,) * self.num_agents
        self.merge_lane = self.road.lane("b", "c", 1)

    def default_params(self) -> MergeCavsParams:
        raise NotImplementedError  # built by make_merge_cavs from the config

    def initial_vehicles(self, key, params: MergeCavsParams):
        """``_reset`` and ``_make_vehicles`` with the draws from ``key``."""
        return self.place(self.draws(key), params)

    def draws(self, key) -> dict:
        """The random numbers of ``_reset``: the counts ``num_cav`` and ``num_hdv``, the order in which the spawn
        points are taken (``main_order``, ``ramp_order``: permutations of 0..5) and per vehicle slot the
        ``speed`` (U(25, 27) m/s) and ``position`` noise (U(-1.5, 1.5) m)."""
        dtype = L.float_dtype()
        k_cav, k_hdv, k_main, k_ramp, k_speed, k_pos = jax.random.split(key, 6)
        n = self.num_vehicles
        return dict(num_cav=jax.random.randint(k_cav, (), self.cav_range[0], self.cav_range[1] + 1),
                    num_hdv=jax.random.randint(k_hdv, (), self.hdv_range[0], self.hdv_range[1] + 1),
                    main_order=jax.random.permutation(k_main, len(MAIN_SPAWNS)),
                    ramp_order=jax.random.permutation(k_ramp, len(RAMP_SPAWNS)),
                    speed=jax.random.uniform(k_speed, (n,), dtype, *SPEED_RANGE),
                    position=jax.random.uniform(k_pos, (n,), dtype, -POSITION_NOISE, POSITION_NOISE))

    def place(self, draws: dict, params: MergeCavsParams) -> dict:
        """Per-slot initial values from the draws. Spawn points are taken in the order ``main_order`` /
        ``ramp_order`` list them, CAVs first: the first ``num_cav // 2`` CAVs and ``num_hdv // 2`` HDVs on the
        main road, the others on the ramp (``lane.position(s, 0)``)."""
        dtype = L.float_dtype()
        K, Hs = self.num_agents, self.num_hdv_slots
        n_cav = jnp.asarray(draws["num_cav"], jnp.int32)
        n_hdv = jnp.asarray(draws["num_hdv"], jnp.int32)
        cav_main, hdv_main = n_cav // 2, n_hdv // 2
        i = jnp.arange(K)
        j = jnp.arange(Hs)
        alive = jnp.concatenate([i < n_cav, j < n_hdv])
        on_main = jnp.concatenate([i < cav_main, j < hdv_main])
        # index into the main / ramp spawn order: CAVs take the first points of each road, HDVs the next ones
        main_idx = jnp.concatenate([i, cav_main + j])
        ramp_idx = jnp.concatenate([i - cav_main, (n_cav - cav_main) + j - hdv_main])
        pick = lambda order, idx, points: jnp.asarray(points, dtype)[order[jnp.clip(idx, 0, len(points) - 1)]]
        s = jnp.where(on_main, pick(draws["main_order"], main_idx, MAIN_SPAWNS),
                      pick(draws["ramp_order"], ramp_idx, RAMP_SPAWNS))
        s = s + jnp.asarray(draws["position"], dtype)
        x = jnp.where(alive, s, 0.0)  # both start lanes run along +x from x = 0
        y = jnp.where(alive & ~on_main, RAMP_Y, 0.0).astype(dtype)
        speed = jnp.where(alive, jnp.asarray(draws["speed"], dtype), 0.0)
        pad = self.num_slots - self.num_vehicles
        fill = lambda a, val: jnp.concatenate([a, jnp.full((pad,), val, a.dtype)])
        return dict(x=fill(x, 0.0), y=fill(y, 0.0), heading=jnp.zeros(self.num_slots, dtype),
                    speed=fill(speed, 0.0), alive=fill(alive, False),
                    delta=jnp.full((self.num_slots,), params.idm.delta, dtype))

    def headway(self, state) -> jax.Array:
        """``_compute_headway_distance`` of each agent ``[K]``: the smallest ``x_v - x_ego > 0`` over the alive
        vehicles on the agent's lane or, unless it is on the merge lane, on its next lane; at most 60 m."""
        idx = np.asarray(self.controlled)
        lane = state.lane[idx]
        s, _ = L.local_coordinates(self.road.lanes, lane, state.x[idx], state.y[idx])
        none = -jnp.ones((1,), jnp.int32)
        zero = jnp.zeros((), jnp.int32)
        nxt = jax.vmap(lambda q, sq: self.road.next_lane(q, sq, none, none, zero, zero)[0])(lane, s)
        gap = state.x[None, :] - state.x[idx][:, None]  # [K, V]
        same = state.lane[None, :] == lane[:, None]
        following = (lane != self.merge_lane)[:, None] & (state.lane[None, :] == nxt[:, None])
        ahead = state.alive[None, :] & (gap > 0) & (same | following)
        return jnp.minimum(jnp.min(jnp.where(ahead, gap, jnp.inf), axis=1), HEADWAY_CAP).astype(state.x.dtype)

    def outcome(self, prev, state, action, params: MergeCavsParams):
        idx = np.asarray(self.controlled)
        dtype = state.x.dtype
        present = state.alive[idx]
        crashed = state.crashed[idx] & present
        col = crashed.astype(dtype)
        speed = state.speed[idx]
        lo, hi = params.reward_speed_range
        high_speed = jnp.clip(0 + (speed - lo) * (1 - 0) / (hi - lo), 0, 1)
        on_merge = state.lane[idx] == self.merge_lane
        merging = jnp.where(on_merge, -jnp.exp(-(state.x[idx] - MERGE_END) ** 2 / (10 * ENDS[2])), 0.0)
        headway = self.headway(state)
        moving = speed > 0
        ratio = headway / (params.headway_time * jnp.where(moving, speed, 1.0))
        headway_term = jnp.where(moving, jnp.log(ratio), 0.0)
        reward = (params.collision_reward * (-1 * col) + params.high_speed_reward * high_speed
                  + params.merging_lane_cost * merging + params.headway_cost * jnp.minimum(headway_term, 0.0))
        reward = jnp.where(present, reward, 0.0).astype(dtype)
        cost = jnp.where(present, params.collision_cost * col, 0.0).astype(dtype)
        terminated = jnp.any(crashed) | ~present
        zero = lambda a: jnp.where(present, a, 0.0).astype(dtype)  # absent agents: no terms
        n_present = jnp.maximum(jnp.sum(present), 1).astype(dtype)
        info = {"alive": present,
                "mean_reward": jnp.sum(reward) / n_present,
                "average_speed": jnp.sum(jnp.where(present, speed, 0.0)) / n_present,
                "rewards": {"collision_reward": col, "high_speed_reward": zero(high_speed),
                            "merging_lane_cost": zero(merging), "headway_cost": zero(headway_term),
                            "headway": jnp.where(present, headway, HEADWAY_CAP).astype(dtype)}}
        return reward, cost, terminated, info


class MergeCavsEnv(TrafficEnv):
    """A :class:`TrafficEnv` whose absent agents observe zeros."""

    has_absent_agents = True  # info["alive"] flags the agents that drive this episode

    def observe(self, state, params, key=None):
        obs = super().observe(state, params, key)
        present = state.alive[np.asarray(self.controlled)]
        return jnp.where(present[:, None, None], obs, 0.0).astype(obs.dtype)


def make_merge_cavs(name: str = NAME, env_config: dict | None = None, **overrides) -> MergeCavsEnv:
    """``merge-cavs-v0`` from MARL_CAVs' config keys (``env_config`` and/or keywords).

    Keys: ``traffic_density`` (1, 2, 3 or ``"easy"``, ``"medium"``, ``"hard"``), ``COLLISION_REWARD``,
    ``HIGH_SPEED_REWARD``, ``HEADWAY_COST``, ``HEADWAY_TIME``, ``MERGING_LANE_COST``, ``reward_speed_range``,
    ``duration`` (s), the frequencies, ``observation`` and ``action`` (highway-env's forms; defaults MARL_CAVs'
    ``Kinematics`` options :data:`OBSERVATION` and target speeds 10..30 m/s in 5 steps), ``safety_guarantee`` and
    ``action_masking`` (False only: MARL_CAVs' safety supervisor
    and action masks belong to its learning method), plus ``num_slots`` (>= the density's most CAVs + most HDVs),
    ``collision_cost`` and ``idm`` (default MARL_CAVs' driver constants; a dict changes some of them). Unknown keys
    and bad values raise ``ValueError`` naming them and what is allowed.
    """
    cfg = dict(DEFAULTS)
    cfg["observation"] = dict(OBSERVATION)
    cfg["action"] = {"type": "DiscreteMetaAction", "target_speeds": list(np.linspace(10, 30, 5))}
    given = CV.config_given(name, cfg, OWN_KEYS, env_config, overrides)  # connected lanes: none on this road
    cfg.update(given)

    density = density_of(name, cfg["traffic_density"])
    for key in ("safety_guarantee", "action_masking"):
        if cfg[key] is not False:
            raise ValueError(f"{name}: {key} must be False: MARL_CAVs' safety supervisor and action masks are "
                             f"part of its learning method, not of the environment; got {cfg[key]!r}")
    sim = CV.int_value(name, "simulation_frequency", cfg["simulation_frequency"], 1)
    pol = CV.int_value(name, "policy_frequency", cfg["policy_frequency"], 1, sim)
    _, hi_c, _, hi_h = DENSITIES[density]
    total = hi_c + hi_h
    num_slots = CV.int_value(name, "num_slots", cfg.get("num_slots", total), total)
    obs_cfg = CV.observation_config(name, cfg["observation"])
    action = CV.meta_action_config(name, cfg["action"])
    rsr = CV.speed_range(name, cfg["reward_speed_range"])
    idm = CV.idm_params(name, cfg.get("idm"), CAVS_IDM)
    num = lambda key, **kw: CV.number_value(name, key, cfg[key], **kw)
    params = MergeCavsParams(
        duration=num("duration", positive=True),
        collision_cost=CV.cost_value(name, "collision_cost", cfg.get("collision_cost", 5.0)),
        target_speeds=np.asarray(action["target_speeds"], np.float64),
        idm=idm,
        obstacles=None,
        collision_reward=num("COLLISION_REWARD"), high_speed_reward=num("HIGH_SPEED_REWARD"),
        headway_cost=num("HEADWAY_COST"), headway_time=num("HEADWAY_TIME", positive=True),
        merging_lane_cost=num("MERGING_LANE_COST"), reward_speed_range=rsr,
    )
    task = MergeCavsTask(density, num_slots, sim, pol, obs_cfg)
    params = params.replace(obstacles=np.array([[task.obstacle[0], task.obstacle[1], 0.0, OBSTACLE_SIZE,
                                                 OBSTACLE_SIZE]]))
    return MergeCavsEnv(task, params)
