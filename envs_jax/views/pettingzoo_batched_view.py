"""Batched PettingZoo view: N parallel environments of one scenario stepped in one jitted call.

>>> import envs_jax, numpy as np
>>> from envs_jax.views import BatchedPettingZooDrivingEnv
>>> envs = BatchedPettingZooDrivingEnv(envs_jax.make("merge"), num_envs=1024)
>>> observations, infos = envs.reset(seed=0)                 # {agent: [1024, *obs_shape]}
>>> actions = {a: np.random.randint(0, 5, 1024) for a in envs.possible_agents}
>>> observations, rewards, terminations, truncations, infos = envs.step(actions)

The dict-of-agents API of :class:`~envs_jax.views.pettingzoo_view.PettingZooDrivingEnv` with
every value batched over environments (leading axis N), as SuperSuit-style vectorised
PettingZoo environments return it; one ``step`` is one compiled call for all N environments
(idle actions for finished agents, step, auto-reset) and one copy to numpy.

* Every agent of every environment is always present. ``infos[agent]["active"]`` ``[N]`` says
  whether the agent was live when the step began (PettingZoo's ``agents``): its action was
  used and its reward, cost, termination and truncation are meaningful. For an agent that had
  already finished, the action is ignored (the idle action drives the car), reward and cost
  are 0 and ``terminations`` / ``truncations`` repeat how it finished.
* An environment whose live agents have all finished is reset in the same call (PettingZoo's
  "agents is empty"): ``infos[agent]["episode_over"]`` flags it, ``infos[agent]["final_obs"]``
  keeps the agent's last observation of the finished episode, and ``observations`` are the new
  episode's first. ``state()`` is ``[N, K * obs_size]``.
* ``infos[agent]``: ``cost`` and the simulator's per-agent flags and reward terms
  (:func:`~envs_jax.views.spaces.agent_info`), each ``[N]``. With
  ``safe=True``, ``step`` returns ``(obs, rewards, costs, terminations, truncations, infos)``.

Bad input raises :class:`~envs_jax.views.spaces.InvalidAction` (a ``ValueError``): unknown or
missing agents (every possible agent needs an ``[N]`` (discrete) or ``[N, d]`` (continuous)
array, finished ones included), or the wrong shape, dtype or range; ``step`` before ``reset``
raises :class:`~envs_jax.views.spaces.ResetNeeded`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.utils import seeding

from envs_jax.views.spaces import AgentSpec, InvalidAction, ResetNeeded, agent_info, host_key


def batched_step_fn(env, params):
    """The pure, vmapped step of N environments with PettingZoo's finished-agent rule and auto-reset.

    ``step(keys[N], states, actions[N, K, ...], active[N, K]) -> (states, active, out)``.
    """
    spec = AgentSpec.of(env, params)
    idle = spec.idle()

    def one(key, state, action, active):
        key_step, key_reset = jax.random.split(key)
        mask = active.reshape(active.shape + (1,) * (action.ndim - 1))
        action = jnp.where(mask, action, idle)
        obs, st, reward, cost, _, info = env.step(key_step, state, action, params)
        terminated, truncated = info["terminated"], jnp.broadcast_to(info["truncated"], active.shape)
        still = active & ~(terminated | truncated)
        over = ~jnp.any(still)
        obs_re, st_re = env.reset(key_reset, params)
        new_state = jax.tree.map(lambda a, b: jnp.where(over, a, b), st_re, st)
        flags = agent_info(info, spec.num_agents)
        out = dict(obs=jnp.where(over, obs_re, obs), final_obs=obs,
                   reward=jnp.where(active, reward, 0), cost=jnp.where(active, cost, 0),
                   terminated=terminated, truncated=truncated, active=active,
                   episode_over=jnp.broadcast_to(over, active.shape), flags=flags)
        return new_state, jnp.where(over, jnp.ones_like(still), still), out

    return jax.vmap(one)


class BatchedPettingZooDrivingEnv:
    """N PettingZoo-style environments in one jitted call (see the module docstring)."""

    metadata = {"name": "jaxsmarl_driving_batched", "render_modes": []}

    def __init__(self, env, num_envs: int, params=None, *, safe: bool = False):
        if not isinstance(num_envs, (int, np.integer)) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        self.env = env
        self.params = env.default_params if params is None else params
        self.spec = AgentSpec.of(env, self.params)
        self.num_envs = int(num_envs)
        self.safe = bool(safe)
        self.metadata = {**type(self).metadata, "name": f"jaxsmarl_{env.name}_batched"}
        self.possible_agents = self.spec.agents
        self.agents = list(self.possible_agents)
        self._observation_spaces = {a: self.spec.gymnasium_observation_space() for a in self.possible_agents}
        self._action_spaces = {a: self.spec.gymnasium_action_space() for a in self.possible_agents}
        self.state_space = self.spec.gymnasium_state_space()
        self._reset_fn = jax.jit(jax.vmap(lambda key: env.reset(key, self.params)))
        self._step_fn = jax.jit(batched_step_fn(env, self.params))
        self._np_random = None
        self._key = None
        self._states = None
        self._active = None
        self._obs = None

    def __repr__(self):
        return f"BatchedPettingZooDrivingEnv({self.env!r}, num_envs={self.num_envs})"

    def observation_space(self, agent):
        """One environment's observation space of ``agent`` (batched values add a leading N axis)."""
        return self._observation_spaces[self._known(agent)]

    def action_space(self, agent):
        return self._action_spaces[self._known(agent)]

    def _known(self, agent):
        if agent not in self._action_spaces:
            raise ValueError(f"{self.spec.name}: unknown agent {agent!r}; the agents are {self.possible_agents}")
        return agent

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Reset all N environments; ``options`` is accepted and unused."""
        if seed is not None or self._np_random is None:
            self._np_random, _ = seeding.np_random(seed)
        key, key_reset = jax.random.split(host_key(self._np_random))
        self._key = key
        obs, self._states = self._reset_fn(jax.random.split(key_reset, self.num_envs))
        self._active = jnp.ones((self.num_envs, self.spec.num_agents), bool)
        self._obs = np.asarray(obs, self.spec.obs_dtype)
        return ({a: self._obs[:, i].copy() for i, a in enumerate(self.possible_agents)},
                {a: {} for a in self.possible_agents})

    def _stack(self, actions) -> np.ndarray:
        if not isinstance(actions, dict):
            raise InvalidAction(f"{self.spec.name}: actions must be a dict {{agent: [N] array}} for "
                                f"{self.possible_agents}, got {type(actions).__name__}")
        unknown = sorted(str(a) for a in actions if a not in self.possible_agents)
        missing = [a for a in self.possible_agents if a not in actions]
        if unknown or missing:
            raise InvalidAction(f"{self.spec.name}: actions must have exactly the keys {self.possible_agents} "
                                f"(finished agents' entries are ignored); unknown {unknown}, missing {missing}")
        return np.stack([self.spec.check_action(a, actions[a], batch=(self.num_envs,)) for a in self.possible_agents],
                        axis=1)

    def step(self, actions: dict):
        if self._states is None:
            raise ResetNeeded(f"{self.spec.name}: call reset() before step()")
        action = self._stack(actions)
        self._key, key = jax.random.split(self._key)
        self._states, self._active, out = self._step_fn(jax.random.split(key, self.num_envs), self._states,
                                                        action, self._active)
        out = jax.device_get(out)
        self._obs = np.asarray(out["obs"], self.spec.obs_dtype)
        agents = self.possible_agents
        observations = {a: self._obs[:, i].copy() for i, a in enumerate(agents)}
        rewards = {a: np.asarray(out["reward"][:, i], np.float64) for i, a in enumerate(agents)}
        costs = {a: np.asarray(out["cost"][:, i], np.float64) for i, a in enumerate(agents)}
        terminations = {a: np.asarray(out["terminated"][:, i], bool) for i, a in enumerate(agents)}
        truncations = {a: np.asarray(out["truncated"][:, i], bool) for i, a in enumerate(agents)}
        infos = {a: {"cost": costs[a], "active": np.asarray(out["active"][:, i], bool),
                     "episode_over": np.asarray(out["episode_over"][:, i], bool),
                     "final_obs": np.asarray(out["final_obs"][:, i], self.spec.obs_dtype),
                     **jax.tree.map(lambda v, i=i: np.asarray(v[:, i]), out["flags"])}
                 for i, a in enumerate(agents)}
        if self.safe:
            return observations, rewards, costs, terminations, truncations, infos
        return observations, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """Global states ``[N, K * obs_size]``: every agent's observation flattened, in agent order."""
        if self._obs is None:
            raise ResetNeeded(f"{self.spec.name}: call reset() before state()")
        return self._obs.reshape(self.num_envs, -1).copy()

    def close(self):
        pass
