"""The deterministic actor of the MADDPG family and its factory, :func:`make_actor` (docs/design.md, networks and
layouts): an MLP ``hidden`` with ReLU, output ``max_action * tanh`` (the authors' ``Actor``, docs/algorithms.md),
its layers named by :func:`jaxsmarl.networks.layer_name`."""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxsmarl import columns
from jaxsmarl.layout import layout as current_layout
from jaxsmarl.network import Network
from jaxsmarl.networks import Dense, layer_name

__all__ = ["Actor", "actor_columns", "make_actor"]


class Actor(nn.Module):
    """Deterministic actor: MLP ``hidden`` with ReLU, output ``max_action * tanh`` (authors' ``Actor``)."""

    hidden: Sequence[int] = (64, 64, 64)
    action_dim: int = 1
    max_action: float = 1.0
    init_scheme: str = "torch"

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for i, h in enumerate(self.hidden):
            x = nn.relu(Dense(h, self.init_scheme, name=layer_name(i))(x))
        out = Dense(self.action_dim, self.init_scheme, name=layer_name(len(self.hidden)))(x)
        return self.max_action * jnp.tanh(out)


def actor_columns(params, x: jax.Array, max_action: float) -> jax.Array:
    """:class:`Actor` (the same function) in the column layout of :mod:`jaxsmarl.columns`: ``[B, D] -> [B, k]``."""
    p = params["params"]
    layers = [p[layer_name(i)] for i in range(len(p))]
    h = x.T
    for layer in layers[:-1]:
        h = nn.relu(columns.dense(layer, h))
    return (max_action * jnp.tanh(columns.dense(layers[-1], h))).T


def make_actor(in_dim: int, hidden: Sequence[int] = (64, 64, 64), action_dim: int = 1, max_action: float = 1.0,
               init_scheme: str = "torch") -> Network:
    """:class:`Actor` on ``in_dim`` inputs as a :class:`jaxsmarl.network.Network` in the layout of
    :func:`jaxsmarl.layout.layout` (``apply_update``: :func:`actor_columns` in the column layout). ``apply`` is the
    module's, so it takes flax's keyword arguments (``capture_intermediates``)."""
    module = Actor(tuple(hidden), action_dim, max_action, init_scheme)
    lay = current_layout()
    init = lambda key: module.init(key, jnp.zeros((1, in_dim), jnp.float32))
    apply_update = (lambda p, x: actor_columns(p, x, max_action)) if lay == "columns" else module.apply
    return Network(lay, init, module.apply, apply_update)
