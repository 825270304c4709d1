"""What every view needs to know about one agent of an environment, read from the env itself.

``AgentSpec.of(env)`` reads the number of agents ``K``, one agent's observation shape, dtype and
bounds, and the action kind (``K`` discrete meta-actions in ``0..n-1``, or ``K`` continuous vectors
in ``[-1, 1]^d``) from the env (``num_agents``, ``obs_shape``, ``discrete``, ``num_actions``,
``action_shape`` and the shapes its ``reset`` returns). It serves the two-agent scenarios
(``[K, 8]`` observations) and the traffic tasks alike (``[K, vehicles_count, F]`` Kinematics,
``[K, C, H, W]`` occupancy grids); nothing here assumes two agents or a flat observation. It
builds the per-agent spaces of each ecosystem (JaxMARL's and Gymnasium's, imported lazily so that
a view only needs its own package) and checks host-side actions: an action of the wrong shape,
dtype or range, or a NaN, raises :class:`InvalidAction` (a ``ValueError``) that names the agent
and what is allowed.
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import vehicle as V
from envs_jax.occupancy_grid import OccupancyGridConfig

IDLE = V.ACTION_NAMES.index("IDLE")
# info entries that are the random numbers a step drew (kept by the simulator for its parity tests), not outcomes
_DRAWS_SUFFIX = "_draws"


class InvalidAction(ValueError):
    """An action that a view refuses (unknown or missing agent, wrong shape, dtype or range)."""


class ResetNeeded(ValueError, AssertionError):
    """``step`` before ``reset`` or after the episode ended.

    A ``ValueError`` like every bad input here, and an ``AssertionError`` as PettingZoo's
    order-enforcing checks raise for the same misuse.
    """


def agent_names(num_agents: int) -> list[str]:
    """``agent_0 .. agent_{K-1}`` (JaxMARL's and PettingZoo's usual names; agent 0 is the leader)."""
    return [f"agent_{i}" for i in range(int(num_agents))]


@dataclasses.dataclass(frozen=True)
class AgentSpec:
    """Per-agent shapes of an environment (every agent of a scenario or task has the same ones)."""

    name: str
    num_agents: int
    obs_shape: tuple  # one agent's observation: (8,), (vehicles_count, F) or (C, H, W)
    obs_dtype: Any  # numpy dtype of the observations the env returns
    obs_low: float  # the observation bounds (highway-env's: an occupancy grid clipped to [-1, 1], else unbounded)
    obs_high: float
    discrete: bool
    num_actions: int | None  # discrete: meta-actions 0..num_actions-1
    action_dim: int | None  # continuous: vector length d
    action_names: tuple | None  # discrete: the meta-action of each index
    idle_action: int | None  # discrete: the index of IDLE (keep lane and speed)

    @classmethod
    def of(cls, env, params=None) -> "AgentSpec":
        k = int(env.num_agents)
        obs_shape = tuple(int(s) for s in env.obs_shape)
        params = env.default_params if params is None else params
        obs = jax.eval_shape(lambda key: env.reset(key, params)[0], jax.random.key(0))
        if len(obs_shape) < 2 or obs_shape[0] != k or tuple(obs.shape) != obs_shape:
            raise ValueError(f"{env.name}: expected observations of shape (num_agents, ...) = ({k}, ...) as "
                             f"env.obs_shape says, got obs_shape {obs_shape} and reset() observations {obs.shape}")
        action_shape = tuple(int(s) for s in env.action_shape)
        discrete = bool(env.discrete)
        if action_shape[:1] != (k,) or len(action_shape) != (1 if discrete else 2):
            raise ValueError(f"{env.name}: expected action_shape ({k},) (discrete) or ({k}, d) (continuous), "
                             f"got {action_shape}")
        low, high = -math.inf, math.inf
        grid = getattr(env, "obs_config", None)
        if isinstance(grid, OccupancyGridConfig) and grid.clip:
            low, high = -1.0, 1.0
        names = None
        if discrete:
            n = int(env.num_actions)
            names = tuple(getattr(env, "action_names", V.ACTION_NAMES[:n]))
            if len(names) != n or "IDLE" not in names:
                raise ValueError(f"{env.name}: expected {n} meta-action names including IDLE, got {names}")
        return cls(name=str(env.name), num_agents=k, obs_shape=obs_shape[1:], obs_dtype=np.dtype(obs.dtype),
                   obs_low=low, obs_high=high, discrete=discrete,
                   num_actions=int(env.num_actions) if discrete else None,
                   action_dim=None if discrete else action_shape[1], action_names=names,
                   idle_action=names.index("IDLE") if discrete else None)

    @property
    def obs_size(self) -> int:
        """Entries in one agent's observation (its length once flattened; the global state is ``K`` of them)."""
        return math.prod(self.obs_shape)

    @property
    def agents(self) -> list[str]:
        return agent_names(self.num_agents)

    # ---------------------------------------------------------------- actions
    @property
    def action_shape(self) -> tuple[int, ...]:
        """One agent's action shape: ``()`` discrete, ``(d,)`` continuous."""
        return () if self.discrete else (self.action_dim,)

    @property
    def action_dtype(self):
        return np.dtype(np.int32) if self.discrete else np.dtype(np.float32)

    def idle(self, batch: tuple[int, ...] = ()) -> jax.Array:
        """The neutral action (IDLE meta-action, or zero acceleration/steering) for ``batch + (K,)`` agents."""
        shape = batch + (self.num_agents,) + self.action_shape
        if self.discrete:
            return jnp.full(shape, self.idle_action, jnp.int32)
        return jnp.zeros(shape, jnp.float32)

    def allowed(self) -> str:
        if self.discrete:
            return (f"an integer in 0..{self.num_actions - 1} "
                    f"({', '.join(f'{i}={n}' for i, n in enumerate(self.action_names))})")
        return f"a float array of shape ({self.action_dim},) in [-1, 1]"

    def check_action(self, agent: str, value, batch: tuple[int, ...] = ()) -> np.ndarray:
        """One agent's host action (or a batch of them, shape ``batch + action_shape``) as a numpy array.

        Discrete: integers (not bools) in ``0..n-1``. Continuous: finite floats; values outside
        ``[-1, 1]`` are clipped by the simulator as highway-env's ``ContinuousAction`` does, and a
        ``(d,)`` vector may be given as a scalar when ``d == 1``.
        """
        arr = np.asarray(value)
        if arr.dtype == object:
            raise InvalidAction(f"{self.name}: action of {agent} must be {self.allowed()}, got {value!r}")
        if self.discrete:
            if arr.dtype == bool or not np.issubdtype(arr.dtype, np.integer):
                raise InvalidAction(f"{self.name}: action of {agent} must be {self.allowed()}, "
                                    f"got {value!r} (dtype {arr.dtype})")
            if arr.shape != batch:
                raise InvalidAction(f"{self.name}: action of {agent} must have shape {batch} "
                                    f"({self.allowed()}), got shape {arr.shape}")
            if np.any(arr < 0) or np.any(arr >= self.num_actions):
                raise InvalidAction(f"{self.name}: action of {agent} must be {self.allowed()}, got {arr.tolist()}")
            return arr.astype(np.int32)
        if not np.issubdtype(arr.dtype, np.floating):
            raise InvalidAction(f"{self.name}: action of {agent} must be {self.allowed()}, "
                                f"got {value!r} (dtype {arr.dtype})")
        if self.action_dim == 1 and arr.shape == batch:
            arr = arr[..., None]
        if arr.shape != batch + self.action_shape:
            raise InvalidAction(f"{self.name}: action of {agent} must have shape {batch + self.action_shape}, "
                                f"got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise InvalidAction(f"{self.name}: action of {agent} must be finite, got {arr.tolist()}")
        return arr.astype(np.float32)

    def check_action_dict(self, actions, live: list[str], batch: tuple[int, ...] = ()) -> np.ndarray:
        """Stack a ``{agent: action}`` dict into ``batch + (K,) + action_shape``.

        Every agent in ``live`` must have an action; an agent outside ``live`` (finished) may only
        be given ``None`` (PettingZoo's rule for dead agents) and is driven by the idle action;
        a name that is no agent of the scenario is refused.
        """
        if not isinstance(actions, dict):
            raise InvalidAction(f"{self.name}: actions must be a dict {{agent: action}} for agents {live}, "
                                f"got {type(actions).__name__}")
        agents = self.agents
        unknown = sorted(str(a) for a in actions if a not in agents)
        if unknown:
            raise InvalidAction(f"{self.name}: actions for unknown agent(s) {unknown}; the agents are {agents}")
        missing = [a for a in live if a not in actions or actions[a] is None]
        if missing:
            raise InvalidAction(f"{self.name}: no action for live agent(s) {missing}; every agent in {live} "
                                f"needs {self.allowed()}")
        finished = [a for a in actions if a not in live and actions[a] is not None]
        if finished:
            raise InvalidAction(f"{self.name}: agent(s) {finished} already finished this episode; their only "
                                f"valid action is None (live agents: {live})")
        out = np.array(self.idle(batch))
        for i, a in enumerate(agents):
            if a in live:
                out[(slice(None),) * len(batch) + (i,)] = self.check_action(a, actions[a], batch)
        return out

    # ---------------------------------------------------------------- spaces
    def gymnasium_observation_space(self):
        import gymnasium

        return gymnasium.spaces.Box(self.obs_low, self.obs_high, self.obs_shape, self.obs_dtype)

    def gymnasium_state_space(self):
        """The global state for centralised critics: every agent's observation flattened, in agent order."""
        import gymnasium

        return gymnasium.spaces.Box(self.obs_low, self.obs_high, (self.num_agents * self.obs_size,), self.obs_dtype)

    def gymnasium_action_space(self):
        import gymnasium

        if self.discrete:
            return gymnasium.spaces.Discrete(self.num_actions)
        return gymnasium.spaces.Box(-1.0, 1.0, (self.action_dim,), np.float32)

    def jaxmarl_observation_space(self):
        from jaxmarl.environments import spaces

        return spaces.Box(self.obs_low, self.obs_high, self.obs_shape, jnp.dtype(self.obs_dtype))

    def jaxmarl_action_space(self):
        from jaxmarl.environments import spaces

        if self.discrete:
            return spaces.Discrete(self.num_actions)
        return spaces.Box(-1.0, 1.0, (self.action_dim,), jnp.float32)


def agent_info(info: dict, num_agents: int) -> dict:
    """The part of a core ``info`` dict the views report, every leaf ``[K]`` (agent order).

    Per-agent leaves (leading axis ``K``: ``terminated``, ``crashed``, the reward terms, ...) are
    kept and episode-wide scalars (``truncated``, a task's flags) broadcast to ``[K]``; leaves of
    any other shape (per-vehicle-slot diagnostics such as intersection's ``cleared``) and the
    random numbers a step drew (``*_draws``) are left out. Nested dicts keep their nesting.
    Works on numpy and on JAX (traced) values.
    """
    out = {}
    for key, value in info.items():
        if str(key).endswith(_DRAWS_SUFFIX):
            continue
        if isinstance(value, dict):
            sub = agent_info(value, num_agents)
            if sub:
                out[key] = sub
            continue
        xp = jnp if isinstance(value, jax.Array) else np
        value = xp.asarray(value)
        if value.ndim == 0:
            out[key] = xp.broadcast_to(value, (num_agents,))
        elif value.shape == (num_agents,):
            out[key] = value
    return out


def observe(env, state, params):
    """The env's observation of ``state``: ``env.observe(state, params)`` for the traffic tasks,
    ``env.observe(state)`` for the two-agent scenarios."""
    if len(inspect.signature(env.observe).parameters) >= 2:
        return env.observe(state, params)
    return env.observe(state)


def host_key(np_random: np.random.Generator) -> jax.Array:
    """A JAX PRNG key drawn from a Gymnasium/PettingZoo ``np_random`` generator (seeded by ``reset(seed)``)."""
    return jax.random.key(int(np_random.integers(0, 2**31 - 1)))
