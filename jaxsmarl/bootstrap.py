"""Which transitions bootstrap in a TD target: the factor ``(1 - t)`` in ``y = r + gamma (1 - t) Q'``.

Two rules, chosen by the off-policy learners' ``terminal_mask`` option:

* ``"sample"`` (correct): each transition's own terminal flag, so a terminal transition's target is its reward.
* ``"batch_mean"`` (the authors' effective rule, docs/algorithms.md "terminal flag"): every transition
  bootstraps, with the discount scaled by the batch's fraction of non-terminal transitions,
  ``y_k = r_k + gamma (1 - mean_j t_j) Q'_k``. Their buffer keeps done flags as ``[N, 1]`` next to rewards
  ``[N]``, so the target broadcasts to ``[B, B, 1]``; the mean squared error to that tensor has exactly the
  gradient of the mean squared error to ``y_k`` above.

``t`` is an agent's own termination, or also the time limit when ``bootstrap_on_truncation`` is false (the
authors' stored done flag).
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxsmarl.options import TERMINAL_MASKS

__all__ = ["TERMINAL_MASKS", "continuation"]


def continuation(terminated, truncated, rule: str = "sample", bootstrap_on_truncation: bool = True, dtype=None):
    """``1 - t`` for a batch: ``terminated`` bool ``[B, n]`` (per agent), ``truncated`` bool ``[B]`` -> ``[B, n]``.

    ``rule="batch_mean"`` replaces each agent's flags by their mean over the batch axis (axis 0). ``dtype``:
    of the result (default float32)."""
    if rule not in TERMINAL_MASKS:
        raise ValueError(f"terminal_mask must be one of {', '.join(TERMINAL_MASKS)}, got {rule!r}")
    done = terminated if bootstrap_on_truncation else terminated | truncated[..., None]
    done = done.astype(jnp.float32 if dtype is None else dtype)
    if rule == "batch_mean":
        done = jnp.broadcast_to(jnp.mean(done, axis=0, keepdims=True), done.shape)
    return 1.0 - done
