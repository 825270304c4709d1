"""Views of every scenario and traffic task for the frameworks safe-MARL users already run (docs/frameworks.md).

Each view is a thin adapter over the one pure simulator (``envs_jax.make(name)``), not a second
simulator, and reads the number of agents, one agent's observation shape and the action kind
from the env:

* :class:`JaxMARLDrivingEnv` (``jaxmarl_view``): a JaxMARL ``MultiAgentEnv``; jittable, vmappable.
* :class:`PettingZooDrivingEnv` (``pettingzoo_view``): a host-side PettingZoo ``ParallelEnv``.
* :class:`BatchedPettingZooDrivingEnv` (``pettingzoo_batched_view``): N PettingZoo-style
  environments stepped in one jitted call.
* :class:`GymnasiumDrivingEnv` (``gymnasium_view``): one agent as a ``gymnasium.Env``.
* :class:`GymnasiumVectorDrivingEnv` (``gymnasium_vector_view``): a ``gymnasium.vector.VectorEnv``.

Every view can return the safe-RL 6-tuple ``(obs, reward, cost, terminated, truncated, info)``
(Safety-Gymnasium / OmniSafe), and always reports the per-agent cost in its infos. The classes
are imported on first use, so a view needs only its own framework installed.
"""

from __future__ import annotations

import importlib

_CLASSES = {
    "JaxMARLDrivingEnv": "jaxmarl_view",
    "JaxMARLDrivingState": "jaxmarl_view",
    "PettingZooDrivingEnv": "pettingzoo_view",
    "BatchedPettingZooDrivingEnv": "pettingzoo_batched_view",
    "GymnasiumDrivingEnv": "gymnasium_view",
    "GymnasiumVectorDrivingEnv": "gymnasium_vector_view",
    "idle_policy": "partners",
    "random_policy": "partners",
    "AgentSpec": "spaces",
    "InvalidAction": "spaces",
    "ResetNeeded": "spaces",
}

__all__ = sorted(_CLASSES)


def __getattr__(name):
    if name in _CLASSES:
        return getattr(importlib.import_module(f"envs_jax.views.{_CLASSES[name]}"), name)
    raise AttributeError(f"module 'envs_jax.views' has no attribute {name!r}")
