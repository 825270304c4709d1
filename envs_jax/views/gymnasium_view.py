"""Gymnasium view: one agent of a scenario as a ``gymnasium.Env`` (host side, numpy in and out).

>>> import envs_jax
>>> from envs_jax.views import GymnasiumDrivingEnv, idle_policy
>>> base = envs_jax.make("racetrack")
>>> env = GymnasiumDrivingEnv(base, agent=0, partner_policy=idle_policy(base))
>>> obs, info = env.reset(seed=0)
>>> obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
>>> info["cost"]

For a single-agent task (``env.num_agents == 1``: ``highway-v0``, ``racetrack-v0``, ... with
one controlled vehicle) the view is that task, and no partner policy is needed:

>>> env = GymnasiumDrivingEnv(envs_jax.make("highway-fast-v0"))   # observation_space Box (5, 5)

Observations have one agent's shape as the env returns it (``(8,)``, ``(vehicles_count, F)``
or ``(C, H, W)``). For a K-agent scenario or task it shows one agent (``agent``: index or
``"agent_i"``) while the other K - 1 are driven by ``partner_policy(key, obs_others) ->
actions_others``, a jittable function of their observations ``[K - 1, *obs_shape]``
(``envs_jax.views.idle_policy(env)``, ``random_policy(env)``, or a trained policy); without
one, a K > 1 env raises ``ValueError`` pointing at the multi-agent views
(``PettingZooDrivingEnv``, ``JaxMARLDrivingEnv``), which control every agent.

* ``terminated`` is the viewed agent's own termination (crash, arrival, off-road) and
  ``truncated`` the time limit; the episode ends for the view on either, even if partners
  still drive.
* ``info``: ``cost`` and the agent's ``crashed`` / ``arrived`` / ``on_road`` flags, a task's
  reward terms and the episode-wide flags (:func:`~envs_jax.views.spaces.agent_info`). With
  ``safe=True`` ``step`` returns Safety-Gymnasium's ``(obs, reward, cost, terminated, truncated, info)``.
* ``render_mode="rgb_array"``: ``render()`` draws the whole scene (every car) as an RGB frame;
  without a render mode it warns and returns None (Gymnasium's convention).

Bad input: an action of the wrong shape, dtype or range (or NaN) raises :class:`InvalidAction`
(a ``ValueError`` and ``gymnasium.error.InvalidAction``); ``step`` before ``reset`` or after the
episode ended raises :class:`ResetNeeded` (a ``ValueError`` and ``gymnasium.error.ResetNeeded``).
"""

from __future__ import annotations

import weakref
from typing import Callable

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.views import spaces as S
from envs_jax.views.spaces import AgentSpec, agent_info, host_key, observe


class InvalidAction(S.InvalidAction, gymnasium.error.InvalidAction):
    """A refused action: both a ``ValueError`` and Gymnasium's ``InvalidAction``."""


class ResetNeeded(S.ResetNeeded, gymnasium.error.ResetNeeded):
    """``step`` before ``reset`` or after the episode ended: also Gymnasium's ``ResetNeeded``."""


def agent_index(spec: AgentSpec, agent) -> int:
    """The index of ``agent`` (an int or an ``"agent_i"`` name); ``ValueError`` if there is none."""
    if isinstance(agent, str) and agent in spec.agents:
        return spec.agents.index(agent)
    if isinstance(agent, (int, np.integer)) and not isinstance(agent, bool) and 0 <= agent < spec.num_agents:
        return int(agent)
    raise ValueError(f"{spec.name}: agent must be an index in 0..{spec.num_agents - 1} or one of {spec.agents}, "
                     f"got {agent!r}")


def single_agent_step(env, params, index: int, partner_policy: Callable | None):
    """``step(key, state, action) -> (obs[K, D], state, reward[K], cost[K], done, info)``: a pure step of
    the whole scenario where agent ``index`` takes ``action`` and the others ``partner_policy``."""
    spec = AgentSpec.of(env, params)
    others = [j for j in range(spec.num_agents) if j != index]

    def step(key, state, action):
        key_partner, key_step = jax.random.split(key)
        if others:
            obs_all = observe(env, state, params)
            partner = jnp.asarray(partner_policy(key_partner, obs_all[jnp.asarray(others)]))
            want = (len(others),) + spec.action_shape
            if spec.action_dim == 1 and partner.shape == want[:1]:
                partner = partner[:, None]
            kind = jnp.integer if spec.discrete else jnp.floating
            if partner.shape != want or not jnp.issubdtype(partner.dtype, kind):
                raise ValueError(f"{spec.name}: partner_policy must return {'integer' if spec.discrete else 'float'} "
                                 f"actions of shape {want} for agents {[spec.agents[j] for j in others]}, "
                                 f"got {partner.dtype} {partner.shape}")
            full = jnp.insert(partner.astype(spec.action_dtype), index, jnp.asarray(action, spec.action_dtype), axis=0)
        else:
            full = jnp.asarray(action, spec.action_dtype)[None]
        return env.step(key_step, state, full, params)

    return step


def require_partner(spec: AgentSpec, partner_policy) -> None:
    if spec.num_agents > 1 and partner_policy is None:
        raise ValueError(
            f"{spec.name} has {spec.num_agents} agents: a single-agent Gymnasium view needs "
            f"partner_policy=(key, obs_others) -> actions_others for the other {spec.num_agents - 1} "
            f"(e.g. envs_jax.views.idle_policy(env)); to control every agent use the multi-agent views "
            f"envs_jax.views.PettingZooDrivingEnv or envs_jax.views.JaxMARLDrivingEnv")
    if partner_policy is not None and not callable(partner_policy):
        raise ValueError(f"{spec.name}: partner_policy must be a function (key, obs_others) -> actions_others, "
                         f"got {partner_policy!r}")


_COMPILED: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def compiled_single_agent_step(env, params, index: int, partner_policy):
    """``jax.jit(single_agent_step(...))``, shared by every view of the same env, params, agent and partner.

    A single-agent task needs no program of its own: the step is the env's compiled ``step`` with
    the key that :func:`single_agent_step` would pass it."""
    if AgentSpec.of(env, params).num_agents == 1:
        def direct(key, state, action):
            _, key_step = jax.random.split(key)
            return env.step(key_step, state, np.asarray(action)[None], params)

        return direct
    per_env = _COMPILED.setdefault(env, {})
    key = (id(params), index, id(partner_policy))
    if key not in per_env:  # the value keeps params and the policy alive, so their ids stay theirs
        per_env[key] = (jax.jit(single_agent_step(env, params, index, partner_policy)), params, partner_policy)
    return per_env[key][0]


class GymnasiumDrivingEnv(gymnasium.Env):
    """One agent of a jaxsmarl scenario as a ``gymnasium.Env`` (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, env, params=None, *, agent=0, partner_policy: Callable | None = None,
                 render_mode: str | None = None, safe: bool = False):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or one of {self.metadata['render_modes']}, "
                             f"got {render_mode!r}")
        self.params = env.default_params if params is None else params
        self.spec_ = AgentSpec.of(env, self.params)
        require_partner(self.spec_, partner_policy)
        self.env = env
        self.agent_index = agent_index(self.spec_, agent)
        self.agent = self.spec_.agents[self.agent_index]
        self.partner_policy = partner_policy
        self.metadata = {**type(self).metadata, "render_fps": env.policy_frequency}
        self.render_mode = render_mode
        self.safe = bool(safe)
        self.observation_space = self.spec_.gymnasium_observation_space()
        self.action_space = self.spec_.gymnasium_action_space()
        self._step_fn = compiled_single_agent_step(env, self.params, self.agent_index, partner_policy)
        self._key = None
        self._state = None
        self._over = True
        self._renderer = None

    def __repr__(self):
        return f"GymnasiumDrivingEnv({self.env!r}, agent={self.agent!r})"

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        """Start an episode; ``options`` is accepted and unused."""
        super().reset(seed=seed)
        self._key, key_reset = jax.random.split(host_key(self.np_random))
        obs, self._state = self.env.reset(key_reset, self.params)
        self._over = False
        return np.asarray(obs[self.agent_index], self.spec_.obs_dtype), {}

    def step(self, action):
        if self._state is None:
            raise ResetNeeded(f"{self.spec_.name}: call reset() before step()")
        if self._over:
            raise ResetNeeded(f"{self.spec_.name}: the episode ended (terminated or truncated); call reset()")
        try:
            action = self.spec_.check_action(self.agent, action)
        except S.InvalidAction as e:
            raise InvalidAction(str(e)) from None
        self._key, key_step = jax.random.split(self._key)
        obs, self._state, reward, cost, _, info = self._step_fn(key_step, self._state, action)
        obs, reward, cost, info = jax.device_get((obs, reward, cost, info))
        i = self.agent_index
        terminated, truncated = bool(info["terminated"][i]), bool(info["truncated"])
        self._over = terminated or truncated
        cost_i = float(cost[i])
        info_out = {"cost": cost_i, **jax.tree.map(lambda v: v[i].copy(), agent_info(info, self.spec_.num_agents))}
        obs_i = np.asarray(obs[i], self.spec_.obs_dtype)
        if self.safe:
            return obs_i, float(reward[i]), cost_i, terminated, truncated, info_out
        return obs_i, float(reward[i]), terminated, truncated, info_out

    def render(self):
        if self.render_mode is None:
            gymnasium.logger.warn("render() called without a render_mode; create the view with render_mode='rgb_array'")
            return None
        if self._state is None:
            raise ResetNeeded(f"{self.spec_.name}: call reset() before render()")
        if self._renderer is None:
            from envs_jax.views.frames import FrameRenderer

            self._renderer = FrameRenderer(self.env, self.params)
        return self._renderer(jax.device_get(self._state))
