"""The episode time limit in policy steps: ``ceil(duration * policy_frequency)``, highway-env's clock.

highway-env truncates once its clock ``time`` (advanced by ``1 / policy_frequency`` per decision) reaches
``duration``; the ``- 1e-6`` absorbs the clock's rounding so that an integral ``duration * policy_frequency``
gives exactly that many steps.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

__all__ = ["step_limit", "episode_step_limit"]


def step_limit(duration, policy_frequency):
    """``ceil(duration * policy_frequency)``: an int for finite Python numbers (infinity, a task without a time
    limit, stays infinite), a float array for arrays (traced in a jitted step, where the env compares its step
    counter with it)."""
    x = duration * policy_frequency - 1e-6
    if isinstance(x, jax.Array):
        return jnp.ceil(x)
    return math.ceil(x) if math.isfinite(x) else x


def episode_step_limit(env, params) -> int | None:
    """``env``'s time limit in policy steps under ``params`` (the env truncates at it), or None when ``params``
    is not concrete (traced) or the env has no ``duration``."""
    try:
        return int(step_limit(float(params.duration), env.policy_frequency))
    except (AttributeError, TypeError, jax.errors.ConcretizationTypeError):
        return None
