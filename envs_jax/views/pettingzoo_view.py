"""PettingZoo view: a scenario as a host-side ``pettingzoo.ParallelEnv`` (numpy in, numpy out).

>>> import envs_jax
>>> from envs_jax.views import PettingZooDrivingEnv
>>> env = PettingZooDrivingEnv(envs_jax.make("roundabout"), render_mode="rgb_array")
>>> observations, infos = env.reset(seed=0)
>>> while env.agents:
...     actions = {a: env.action_space(a).sample() for a in env.agents}
...     observations, rewards, terminations, truncations, infos = env.step(actions)
>>> frame = env.render()                                   # uint8 [H, W, 3]

Each call runs the simulator's compiled ``reset`` / ``step`` (shared by every view built on the
same ``DrivingEnv``) and copies the results to numpy; see :class:`BatchedPettingZooDrivingEnv`
for N environments in one jitted call.

* ``possible_agents`` are ``agent_0 .. agent_{K-1}`` (agent 0 is the leader); an agent leaves
  ``agents`` on the step it terminates (crash, arrival, off-road) or the time limit hits. The
  simulator keeps driving a finished car with the idle action (IDLE, or zero acceleration and
  steering) until the episode ends, i.e. until ``agents`` is empty; finished agents get no
  observations, rewards or infos, and their only valid action is ``None``.
* Observations have one agent's shape (``observation_space(agent).shape``: ``(8,)``,
  ``(vehicles_count, F)`` or ``(C, H, W)``), as the env returns them.
* ``infos[agent]`` holds the agent's ``cost`` and its ``crashed`` / ``arrived`` / ``on_road``
  flags, a task's reward terms, and the episode-wide flags
  (:func:`~envs_jax.views.spaces.agent_info`). With ``safe=True``, ``step`` returns
  Safety-Gymnasium's multi-agent 6-tuple ``(obs, rewards, costs, terminations, truncations, infos)``.
* ``state()`` is the global state for centralised critics: all agents' observations flattened,
  in agent order (``state_space``, ``[K * obs_size]``); ``render()`` an RGB frame
  (``render_mode="rgb_array"``) of every scenario and task: controlled cars green (the two-agent
  scenarios: the follower blue), traffic blue, crashed red.
* ``reset(seed, options)``: ``seed`` seeds the episode stream (the same seed gives the same
  episode); ``options`` is accepted and unused (no scenario option is read from it).

Bad input raises :class:`~envs_jax.views.spaces.InvalidAction` (a ``ValueError``): actions for
unknown agents, a missing action for a live agent, a non-``None`` action for a finished agent,
and actions of the wrong shape, dtype or range (or NaN). ``step`` before ``reset`` or after every
agent finished raises :class:`~envs_jax.views.spaces.ResetNeeded`.
"""

from __future__ import annotations

import jax
import numpy as np
from gymnasium import logger
from gymnasium.utils import seeding
from pettingzoo import ParallelEnv

from envs_jax.views.spaces import AgentSpec, ResetNeeded, agent_info, host_key


class PettingZooDrivingEnv(ParallelEnv):
    """A jaxsmarl scenario as a PettingZoo ``ParallelEnv`` (see the module docstring)."""

    metadata = {"name": "jaxsmarl_driving", "render_modes": ["rgb_array"], "is_parallelizable": True}

    def __init__(self, env, params=None, *, render_mode: str | None = None, safe: bool = False):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, "
                             f"got {render_mode!r}")
        self.env = env
        self.params = env.default_params if params is None else params
        self.spec = AgentSpec.of(env, self.params)
        self.metadata = {**type(self).metadata, "name": f"jaxsmarl_{env.name}",
                         "render_fps": env.policy_frequency}
        self.render_mode = render_mode
        self.safe = bool(safe)
        self.possible_agents = self.spec.agents
        self.agents: list[str] = []
        self._observation_spaces = {a: self.spec.gymnasium_observation_space() for a in self.possible_agents}
        self._action_spaces = {a: self.spec.gymnasium_action_space() for a in self.possible_agents}
        self.state_space = self.spec.gymnasium_state_space()
        self._np_random = None
        self._key = None
        self._state = None
        self._obs = None
        self._renderer = None

    def __repr__(self):
        return f"PettingZooDrivingEnv({self.env!r})"

    def observation_space(self, agent):
        return self._observation_spaces[self._known(agent)]

    def action_space(self, agent):
        return self._action_spaces[self._known(agent)]

    def _known(self, agent):
        if agent not in self._action_spaces:
            raise ValueError(f"{self.spec.name}: unknown agent {agent!r}; the agents are {self.possible_agents}")
        return agent

    # ------------------------------------------------------------------ episode
    def reset(self, seed: int | None = None, options: dict | None = None):
        if seed is not None or self._np_random is None:
            self._np_random, _ = seeding.np_random(seed)
        key = host_key(self._np_random)
        self._key, key_reset = jax.random.split(key)
        obs, self._state = self.env.reset(key_reset, self.params)
        self._obs = np.asarray(obs, dtype=self.spec.obs_dtype)
        self.agents = self._present_agents()
        index = {a: i for i, a in enumerate(self.possible_agents)}
        return {a: self._obs[index[a]].copy() for a in self.agents}, {a: {} for a in self.agents}

    def _present_agents(self) -> list[str]:
        """The agents that take part in the episode just reset: all of them, except in tasks that draw how many
        controlled vehicles an episode has (``has_absent_agents``), where an agent without a vehicle is left out."""
        if not getattr(self.env, "has_absent_agents", False):
            return list(self.possible_agents)
        present = np.asarray(jax.device_get(self._state.alive))[np.asarray(self.env.controlled)]
        return [a for a, p in zip(self.possible_agents, present) if p]

    def step(self, actions: dict):
        if self._state is None:
            raise ResetNeeded(f"{self.spec.name}: call reset() before step()")
        if not self.agents:
            raise ResetNeeded(f"{self.spec.name}: the episode is over (every agent finished); call reset()")
        live = list(self.agents)
        action = self.spec.check_action_dict(actions, live)
        self._key, key_step = jax.random.split(self._key)
        obs, self._state, reward, cost, _, info = self.env.step(key_step, self._state, action, self.params)
        obs, reward, cost, info = jax.device_get((obs, reward, cost, info))
        self._obs = np.asarray(obs, dtype=self.spec.obs_dtype)
        per_agent = agent_info(info, self.spec.num_agents)
        terminated, truncated = np.asarray(info["terminated"], bool), bool(info["truncated"])
        index = {a: i for i, a in enumerate(self.possible_agents)}
        observations = {a: self._obs[index[a]].copy() for a in live}
        rewards = {a: float(reward[index[a]]) for a in live}
        costs = {a: float(cost[index[a]]) for a in live}
        terminations = {a: bool(terminated[index[a]]) for a in live}
        truncations = {a: truncated for a in live}
        infos = {a: {"cost": costs[a], **jax.tree.map(lambda v, i=index[a]: v[i].copy(), per_agent)} for a in live}
        self.agents = [a for a in live if not (terminations[a] or truncations[a])]
        if self.safe:
            return observations, rewards, costs, terminations, truncations, infos
        return observations, rewards, terminations, truncations, infos

    def state(self) -> np.ndarray:
        """Global state ``[K * obs_size]``: every agent's current observation flattened, in agent order."""
        if self._obs is None:
            raise ResetNeeded(f"{self.spec.name}: call reset() before state()")
        return self._obs.reshape(-1).copy()

    def render(self):
        if self.render_mode is None:
            logger.warn("render() called without a render_mode; create the view with render_mode='rgb_array'")
            return None
        if self._state is None:
            raise ResetNeeded(f"{self.spec.name}: call reset() before render()")
        if self._renderer is None:
            from envs_jax.views.frames import FrameRenderer

            self._renderer = FrameRenderer(self.env, self.params)
        return self._renderer(jax.device_get(self._state))

    def close(self):
        self._renderer = None
