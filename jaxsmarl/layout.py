"""The one place where the network layout is chosen (docs/design.md, networks and layouts).

``"columns"``: the update differentiates networks whose dense layers hold samples as columns
(:mod:`jaxsmarl.columns`), each network of a stack run on its own, and carries every network through the
minibatch loops as one vector (:mod:`jaxsmarl.flat`); faster reverse-mode gradients on XLA:CPU, where it is the
default. ``"rows"``: flax modules on samples as rows, stacks of networks batched with ``vmap``; the default on other
backends (a GPU). Both layouts compute the same functions of the same parameter trees.

The environment variable ``JAXSMARL_LAYOUT`` (``columns`` or ``rows``) overrides the choice for the networks built
while it is set, for tests and for users who want the other layout on a backend.
"""

from __future__ import annotations

import os

import jax

__all__ = ["LAYOUTS", "ENV_VAR", "layout"]

LAYOUTS = ("columns", "rows")
ENV_VAR = "JAXSMARL_LAYOUT"


def layout() -> str:
    """The layout of the networks built now: ``$JAXSMARL_LAYOUT`` if set, else ``"columns"`` on XLA:CPU and
    ``"rows"`` elsewhere."""
    forced = os.environ.get(ENV_VAR, "")
    if forced:
        if forced not in LAYOUTS:
            raise ValueError(f"{ENV_VAR} must be one of {', '.join(LAYOUTS)} (or unset), got {forced!r}")
        return forced
    return "columns" if jax.default_backend() == "cpu" else "rows"
