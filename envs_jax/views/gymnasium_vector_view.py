"""Gymnasium vector view: ``num_envs`` copies of one agent's task as a ``gymnasium.vector.VectorEnv``.

>>> import envs_jax
>>> from envs_jax.views import GymnasiumVectorDrivingEnv, idle_policy
>>> base = envs_jax.make("intersection")
>>> envs = GymnasiumVectorDrivingEnv(base, num_envs=64, partner_policy=idle_policy(base))
>>> obs, infos = envs.reset(seed=0)                             # [64, *obs_shape]
>>> obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())

Backed by the vmapped simulator: every ``step`` is one jitted call for all environments
(partners' policy, step and auto-reset included), then one copy to numpy. The agent, partner
policy and episode end are those of :class:`~envs_jax.views.gymnasium_view.GymnasiumDrivingEnv`
(a K > 1 env needs ``partner_policy``, a K = 1 task does not).

Auto-reset (``metadata["autoreset_mode"]``), as Gymnasium's own vector environments do it:

* ``"next_step"`` (Gymnasium's default): the step after an episode ended resets that
  environment (its action is ignored; reward 0, not terminated or truncated, no info keys).
* ``"same_step"``: the environment is reset in the step that ends it; the returned observation
  is the new episode's first, and ``infos["final_obs"]`` / ``infos["final_info"]`` (masks
  ``infos["_final_obs"]``, ``infos["_final_info"]``) hold the last one and its info.

``infos`` are batched as Gymnasium does (an array per key with a ``"_key"`` mask): ``cost`` and
the agent's flags. ``safe=True`` returns ``(obs, rewards, costs, terminations, truncations,
infos)``. Bad input: actions of the wrong shape, dtype or range raise ``InvalidAction``
(``ValueError``); ``step`` before ``reset`` raises ``ResetNeeded``.
"""

from __future__ import annotations

from typing import Callable

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from envs_jax.views import spaces as S
from envs_jax.views.gymnasium_view import InvalidAction, ResetNeeded, agent_index, require_partner, single_agent_step
from envs_jax.views.spaces import AgentSpec, agent_info, host_key

_MODES = {"next_step": AutoresetMode.NEXT_STEP, "same_step": AutoresetMode.SAME_STEP}


def batched_info(values: dict, mask: np.ndarray) -> dict:
    """Gymnasium's vector info layout: each ``[N]`` value under its key with the mask under ``"_key"``
    (a nested dict gets the same layout inside, and its own mask)."""
    out = {}
    for key, value in values.items():
        out[key] = batched_info(value, mask) if isinstance(value, dict) else np.asarray(value).copy()
        out[f"_{key}"] = mask.copy()
    return out


class GymnasiumVectorDrivingEnv(gymnasium.vector.VectorEnv):
    """``num_envs`` auto-resetting copies of one agent's task in one jitted call (see the module docstring)."""

    def __init__(self, env, num_envs: int, params=None, *, agent=0, partner_policy: Callable | None = None,
                 autoreset_mode="next_step", safe: bool = False):
        self.spec_ = AgentSpec.of(env, env.default_params if params is None else params)
        require_partner(self.spec_, partner_policy)
        if not isinstance(num_envs, (int, np.integer)) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
        mode = _MODES.get(autoreset_mode, autoreset_mode)
        if mode not in _MODES.values():
            raise ValueError(f"autoreset_mode must be one of {sorted(_MODES)} (or gymnasium's AutoresetMode "
                             f"NEXT_STEP / SAME_STEP), got {autoreset_mode!r}")
        self.env = env
        self.params = env.default_params if params is None else params
        self.num_envs = int(num_envs)
        self.agent_index = agent_index(self.spec_, agent)
        self.agent = self.spec_.agents[self.agent_index]
        self.autoreset_mode = mode
        self.safe = bool(safe)
        self.metadata = {"autoreset_mode": mode, "render_modes": []}
        self.render_mode = None
        self.single_observation_space = self.spec_.gymnasium_observation_space()
        self.single_action_space = self.spec_.gymnasium_action_space()
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._build(partner_policy)
        self._key = None
        self._states = None
        self._ended = np.zeros(self.num_envs, bool)

    def __repr__(self):
        return f"GymnasiumVectorDrivingEnv({self.env!r}, num_envs={self.num_envs}, agent={self.agent!r})"

    def _build(self, partner_policy):
        env, params, i = self.env, self.params, self.agent_index
        step_one = single_agent_step(env, params, i, partner_policy)
        same_step = self.autoreset_mode == AutoresetMode.SAME_STEP

        def one(key, state, action, ended):
            key_step, key_reset = jax.random.split(key)
            obs, st, reward, cost, _, info = step_one(key_step, state, action)
            obs_re, st_re = env.reset(key_reset, params)
            term, trunc = info["terminated"][i], info["truncated"]
            out = dict(obs=obs[i], reward=reward[i], cost=cost[i], terminated=term, truncated=trunc)
            flags = jax.tree.map(lambda v: v[i], agent_info(info, self.spec_.num_agents))
            if same_step:
                end = term | trunc
                new_state = jax.tree.map(lambda a, b: jnp.where(end, a, b), st_re, st)
                out.update(final_obs=obs[i], obs=jnp.where(end, obs_re[i], obs[i]), ended=end)
            else:  # next_step: an ended environment is reset instead of stepped
                new_state = jax.tree.map(lambda a, b: jnp.where(ended, a, b), st_re, st)
                zero = lambda x: jnp.where(ended, jnp.zeros_like(x), x)
                out.update(obs=jnp.where(ended, obs_re[i], obs[i]), reward=zero(out["reward"]),
                           cost=zero(out["cost"]), terminated=zero(term), truncated=zero(trunc),
                           ended=(term | trunc) & ~ended)
            return new_state, out, flags

        def reset_all(keys):
            obs, st = jax.vmap(env.reset, in_axes=(0, None))(keys, params)
            return obs[:, i], st

        self._reset_fn = jax.jit(reset_all)
        self._step_fn = jax.jit(jax.vmap(one))

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        """Reset every environment; ``seed`` an int (or one per environment); ``options`` unused."""
        if isinstance(seed, (list, tuple)):
            if len(seed) != self.num_envs:
                raise ValueError(f"seed must be an int or a list of {self.num_envs} ints, got {len(seed)} seeds")
            keys = jnp.stack([jax.random.key(int(s)) for s in seed])
            self._np_random, self._np_random_seed = gymnasium.utils.seeding.np_random(int(seed[0]))
        else:
            if seed is not None or getattr(self, "_np_random", None) is None:
                self._np_random, self._np_random_seed = gymnasium.utils.seeding.np_random(seed)
            keys = jax.random.split(host_key(self._np_random), self.num_envs)
        self._key = host_key(self._np_random)
        obs, self._states = self._reset_fn(keys)
        self._ended = np.zeros(self.num_envs, bool)
        return np.asarray(obs, self.spec_.obs_dtype), {}

    def step(self, actions):
        if self._states is None:
            raise ResetNeeded(f"{self.spec_.name}: call reset() before step()")
        try:
            actions = self.spec_.check_action(self.agent, actions, batch=(self.num_envs,))
        except S.InvalidAction as e:
            raise InvalidAction(str(e)) from None
        self._key, key = jax.random.split(self._key)
        keys = jax.random.split(key, self.num_envs)
        self._states, out, flags = self._step_fn(keys, self._states, actions, jnp.asarray(self._ended))
        out, flags = jax.device_get((out, flags))
        reset_now = self._ended  # next_step: these environments were reset by this call
        self._ended = np.asarray(out["ended"], bool)
        stepped = ~reset_now if self.autoreset_mode == AutoresetMode.NEXT_STEP else np.ones(self.num_envs, bool)
        values = {"cost": out["cost"], **flags}
        infos = batched_info(values, stepped)
        if self.autoreset_mode == AutoresetMode.SAME_STEP and self._ended.any():
            final_obs = np.full(self.num_envs, None, dtype=object)
            for n in np.flatnonzero(self._ended):
                final_obs[n] = np.asarray(out["final_obs"][n], self.spec_.obs_dtype)
            final_info = batched_info(values, self._ended)
            infos.update(final_obs=final_obs, _final_obs=self._ended.copy(), final_info=final_info,
                         _final_info=self._ended.copy())
        obs = np.asarray(out["obs"], self.spec_.obs_dtype)
        rewards = np.asarray(out["reward"], np.float64)
        terminations = np.asarray(out["terminated"], bool)
        truncations = np.asarray(out["truncated"], bool)
        if self.safe:
            return obs, rewards, np.asarray(out["cost"], np.float64), terminations, truncations, infos
        return obs, rewards, terminations, truncations, infos
