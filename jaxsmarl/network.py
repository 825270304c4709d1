"""A network as a value: the functions of its parameters that the algorithms call, built once by a factory for
one layout (:mod:`jaxsmarl.layout`), as brax's ``FeedForwardNetwork`` (docs/design.md, networks and layouts).

Every ``apply*`` is the same mathematical function of the same parameter tree; they differ in which derivatives
they support and how fast those are in the chosen layout. The algorithms pick the function by what they need (a
forward pass, the update's reverse-mode gradients, a vjp replayed at one point, a whole rollout) and never by the
layout.
"""

from __future__ import annotations

import dataclasses
from typing import Callable, Optional

__all__ = ["Network"]


@dataclasses.dataclass(frozen=True)
class Network:
    """``init(key) -> params``; ``apply(params, x)``: every derivative (forward and reverse mode), for acting,
    evaluation and ``jax.jvp``; ``apply_update(params, x)``: the form the update's ``jax.grad`` differentiates
    (reverse mode only in the column layout); ``apply_replay(params, x)``: the form for a vjp evaluated many times
    at one point (reverse mode only); ``apply_stack(stacked, x)``: every network of a stack of parameters
    (leading axes) on the same inputs, for a whole rollout (no derivative needed); ``rollout(fn, *xs)``:
    ``fn(*xs)`` for a function of the samples of a whole rollout (rows independent), the way the layout runs it
    (in chunks in the column layout, :func:`jaxsmarl.columns.in_chunks`). A factory leaves out what its network
    does not offer (``None``)."""

    layout: str
    init: Callable
    apply: Callable
    apply_update: Callable
    apply_replay: Optional[Callable] = None
    apply_stack: Optional[Callable] = None
    rollout: Optional[Callable] = None
