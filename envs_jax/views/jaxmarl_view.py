"""JaxMARL view: a scenario as a ``jaxmarl.environments.multi_agent_env.MultiAgentEnv``.

>>> import jax, envs_jax
>>> from envs_jax.views import JaxMARLDrivingEnv
>>> env = JaxMARLDrivingEnv(envs_jax.make("merge"))
>>> obs, state = env.reset(jax.random.key(0))                 # {"agent_0": [8], "agent_1": [8]}
>>> tasks = JaxMARLDrivingEnv(envs_jax.make("highway-fast-v0", controlled_vehicles=3))  # obs [5, 5] per agent
>>> actions = {a: env.action_space(a).sample(jax.random.key(1)) for a in env.agents}
>>> obs, state, rewards, dones, infos = env.step(jax.random.key(2), state, actions)
>>> infos["cost"]                                              # [K] per-agent cost, agent order

It is a real subclass of JaxMARL's ``MultiAgentEnv`` over the one pure simulator (no copy of it):
``reset(key)`` / ``step(key, state, actions)`` are jittable and vmappable, ``step`` auto-resets
when ``dones["__all__"]`` exactly as JaxMARL's base class does (same key split, optional
``reset_state``), and ``step_env`` is the step without reset.

* Agents ``agent_0 .. agent_{K-1}`` (agent 0 is the leader), ``K = env.num_agents``.
* ``dones[agent] = terminated[agent] | truncated`` and ``dones["__all__"]`` is the core's ``done``
  (every agent terminated, or the time limit).
* ``infos``: every leaf has shape ``[K]`` (agent order), as JaxMARL's baselines expect when they
  reshape infos to ``[num_envs * num_agents]``: ``cost``, ``terminated``, ``truncated``,
  ``crashed``, ``arrived``, ``on_road``, a task's reward terms (``infos["rewards"]``) and the
  scenario's own flags (scalars broadcast to ``[K]``); per-vehicle-slot diagnostics of the
  traffic tasks are left out (:func:`~envs_jax.views.spaces.agent_info`).
* The last observation of a finished episode (before the auto-reset) is kept in
  ``state.terminal_obs`` (``{agent: obs}``) for bootstrapping, and also in
  ``infos["terminal_obs"]`` with ``terminal_obs_in_infos=True`` (off by default, since it is
  not ``[K]``-shaped).
* ``observation_space(agent)`` / ``action_space(agent)`` are JaxMARL spaces (``Box`` of one
  agent's observation shape: ``(8,)`` for the two-agent scenarios, ``(vehicles_count, F)`` for
  Kinematics tasks, ``(C, H, W)`` for racetrack-v0's occupancy grid, with highway-env's bounds;
  ``Discrete(n)`` meta-actions or ``Box(-1, 1, (d,))``), ``get_avail_actions(state)`` all-true
  masks (every meta-action is always accepted; an impossible lane change is a no-op, as in
  highway-env), ``world_state(state)`` the global state for centralised critics (all agents'
  observations flattened and concatenated, ``[K * obs_size]``, as JaxMARL's ``CTRolloutManager``
  and MPE world-state wrapper build it), and with ``world_state=True`` the observations also
  carry it under ``"world_state"`` (as SMAX's do for its MAPPO baseline). Policies whose network
  takes flat vectors flatten the per-agent observation themselves (JaxMARL's ``batchify`` does).
* :meth:`step_safe` returns the safe-RL tuple ``(obs, state, rewards, costs, terminations,
  truncations, infos)``: Safety-Gymnasium's ``(obs, reward, cost, terminated, truncated, info)``
  with the state after the observations, as in JaxMARL's own return order.

A discrete action may be a scalar or a one-element vector (JaxMARL's baselines unbatchify to
``[num_envs, 1]``). Bad input: actions for unknown agents, missing agents, or of the wrong shape or dtype raise
``ValueError`` when ``step`` is called (also while tracing under ``jit``); out-of-range or NaN
values raise in eager calls, and inside ``jit`` (values unknown) the simulator's policy applies:
discrete actions clipped to ``0..n-1``, continuous ones clipped to ``[-1, 1]`` with NaN read as 0.
"""

from __future__ import annotations

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jaxmarl.environments.multi_agent_env import MultiAgentEnv, State

from envs_jax.views.spaces import AgentSpec, InvalidAction, agent_info, observe


@struct.dataclass
class JaxMARLDrivingState(State):
    """JaxMARL ``State`` (``done``, ``step``) plus the simulator's state and the last terminal obs."""

    env_state: Any
    terminal_obs: Any  # {agent: obs}: the observation the last step produced, before any auto-reset


class JaxMARLDrivingEnv(MultiAgentEnv):
    """A jaxsmarl scenario as a JaxMARL ``MultiAgentEnv`` (see the module docstring)."""

    def __init__(self, env, params=None, *, world_state: bool = False, terminal_obs_in_infos: bool = False):
        self.params = env.default_params if params is None else params
        self.spec = AgentSpec.of(env, self.params)
        super().__init__(num_agents=self.spec.num_agents)
        self.env = env
        self.include_world_state = bool(world_state)
        self.terminal_obs_in_infos = bool(terminal_obs_in_infos)
        self.observation_spaces = {a: self.spec.jaxmarl_observation_space() for a in self.agents}
        self.action_spaces = {a: self.spec.jaxmarl_action_space() for a in self.agents}
        self.world_state_size = self.spec.num_agents * self.spec.obs_size

    def __repr__(self):
        return f"JaxMARLDrivingEnv({self.env!r}, agents={self.agents})"

    @property
    def name(self) -> str:
        return self.env.name

    @property
    def agent_classes(self) -> dict:
        classes = {"leader": self.agents[:1], "follower": self.agents[1:]}
        return {k: v for k, v in classes.items() if v}

    # ------------------------------------------------------------------ conversions
    def _to_dict(self, stacked) -> dict:
        return {a: stacked[i] for i, a in enumerate(self.agents)}

    def _obs_dict(self, obs) -> dict:
        out = self._to_dict(obs)
        if self.include_world_state:
            out["world_state"] = obs.reshape(-1)
        return out

    def _stack_actions(self, actions) -> jax.Array:
        """Validate a ``{agent: action}`` dict at the Python boundary and stack it to ``[K, ...]``."""
        spec = self.spec
        if not isinstance(actions, dict):
            raise InvalidAction(f"{spec.name}: actions must be a dict {{agent: action}} for {self.agents}, "
                                f"got {type(actions).__name__}")
        unknown = sorted(str(a) for a in actions if a not in self.agents)
        missing = [a for a in self.agents if a not in actions]
        if unknown or missing:
            raise InvalidAction(f"{spec.name}: actions must have exactly the keys {self.agents}; "
                                f"unknown {unknown}, missing {missing}")
        parts = []
        for a in self.agents:
            x = actions[a]
            if spec.discrete and tuple(np.shape(x)) == (1,):  # JaxMARL's baselines pass [1]-shaped discrete actions
                x = x[0]
            if isinstance(x, jax.core.Tracer):
                dtype_ok = jnp.issubdtype(x.dtype, jnp.integer if spec.discrete else jnp.floating)
                shape = tuple(x.shape)
                if spec.action_dim == 1 and shape == ():
                    x, shape = x[None], (1,)
                if not dtype_ok or shape != spec.action_shape:
                    raise InvalidAction(f"{spec.name}: action of {a} must be {spec.allowed()}, "
                                        f"got a traced {x.dtype} array of shape {tuple(x.shape)}")
            else:
                x = spec.check_action(a, np.asarray(x))
            parts.append(jnp.asarray(x))
        return jnp.stack(parts)

    # ------------------------------------------------------------------ API
    @partial(jax.jit, static_argnums=(0,))
    def reset(self, key):
        obs, env_state = self.env.reset(key, self.params)
        state = JaxMARLDrivingState(done=jnp.zeros((), bool), step=env_state.time, env_state=env_state,
                                    terminal_obs=self._to_dict(obs))
        return self._obs_dict(obs), state

    def get_obs(self, state: JaxMARLDrivingState) -> dict:
        return self._obs_dict(observe(self.env, state.env_state, self.params))

    def world_state(self, state: JaxMARLDrivingState) -> jax.Array:
        """Global state ``[K * obs_size]``: every agent's observation flattened, in agent order."""
        return observe(self.env, state.env_state, self.params).reshape(-1)

    @partial(jax.jit, static_argnums=(0,))
    def get_avail_actions(self, state: JaxMARLDrivingState) -> dict:
        n = self.spec.num_actions if self.spec.discrete else self.spec.action_dim
        return {a: jnp.ones((n,), bool) for a in self.agents}

    def step_env(self, key, state: JaxMARLDrivingState, actions: dict):
        """One step without auto-reset: ``obs, state, rewards, dones, infos``."""
        obs, state, rewards, _, dones, infos = self._step_env(key, state, self._stack_actions(actions))
        return obs, state, rewards, dones, infos

    def step(self, key, state: JaxMARLDrivingState, actions: dict, reset_state: JaxMARLDrivingState | None = None):
        """One step; resets (to ``reset_state`` if given) when ``dones["__all__"]``."""
        obs, state, rewards, _, dones, infos = self._step(key, state, self._stack_actions(actions), reset_state)
        return obs, state, rewards, dones, infos

    def step_safe(self, key, state: JaxMARLDrivingState, actions: dict,
                  reset_state: JaxMARLDrivingState | None = None):
        """:meth:`step` as the safe-RL tuple ``(obs, state, rewards, costs, terminations, truncations, infos)``.

        Every element but ``state`` is keyed by agent; ``terminations[agent]`` is the agent's own
        termination and ``truncations[agent]`` the time limit; ``terminations["__all__"]`` and
        ``truncations["__all__"]`` end the episode together (``dones["__all__"]`` of :meth:`step`).
        """
        obs, state, rewards, costs, dones, infos = self._step(key, state, self._stack_actions(actions), reset_state)
        term, trunc = infos["terminated"], infos["truncated"]
        terminations = {**self._to_dict(term), "__all__": jnp.all(term)}
        truncations = {**self._to_dict(trunc), "__all__": dones["__all__"] & ~jnp.all(term)}
        return obs, state, rewards, costs, terminations, truncations, infos

    # ------------------------------------------------------------------ pure parts
    @partial(jax.jit, static_argnums=(0,))
    def _step_env(self, key, state, action):
        obs, env_state, reward, cost, done, info = self.env.step(key, state.env_state, action, self.params)
        infos = {"cost": cost, **agent_info(info, self.num_agents)}
        dones = {a: info["terminated"][i] | info["truncated"] for i, a in enumerate(self.agents)}
        dones["__all__"] = done
        terminal = self._to_dict(obs)
        if self.terminal_obs_in_infos:
            infos["terminal_obs"] = terminal
        new_state = JaxMARLDrivingState(done=done, step=env_state.time, env_state=env_state, terminal_obs=terminal)
        return self._obs_dict(obs), new_state, self._to_dict(reward), self._to_dict(cost), dones, infos

    @partial(jax.jit, static_argnums=(0,))
    def _step(self, key, state, action, reset_state=None):
        key, key_reset = jax.random.split(key)  # JaxMARL's split: step with the first, reset with the second
        obs_st, st, rewards, costs, dones, infos = self._step_env(key, state, action)
        if reset_state is None:
            obs_re, st_re = self.reset(key_reset)
        else:
            st_re = reset_state
            obs_re = self.get_obs(reset_state)
        st_re = st_re.replace(terminal_obs=st.terminal_obs)
        done = dones["__all__"]
        st = jax.tree.map(lambda a, b: jax.lax.select(done, a, b), st_re, st)
        obs = jax.tree.map(lambda a, b: jax.lax.select(done, a, b), obs_re, obs_st)
        return obs, st, rewards, costs, dones, infos
