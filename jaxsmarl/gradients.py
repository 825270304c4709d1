"""Gradient steps of the on-policy updates, and how a network travels through their minibatch loops
(docs/design.md, networks and layouts).

:func:`gradient_update_fn` is one optimiser step on a loss, as brax's ``gradient_update_fn``. :class:`LoopCarry`
packs parameters and optimiser states for a minibatch loop in the layout's form: in the column layout each
network as one vector (:class:`jaxsmarl.flat.Flat`; optax then clips and steps one vector per network instead of
each of its arrays) and a stack of networks as a tuple, stepped one after the other (a ``vmap`` over the stack
would turn every product into a batched one, slower there than separate plain ones); in the row layout the trees
themselves, a stack stepped with ``vmap``. The loss always receives the parameter tree.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
import optax

from jaxsmarl.flat import Flat, from_flat, to_flat
from jaxsmarl.layout import LAYOUTS

__all__ = ["gradient_update_fn", "LoopCarry"]


def _tree(params):
    return params.tree() if isinstance(params, Flat) else params


def gradient_update_fn(loss_fn: Callable, optimizer: optax.GradientTransformation, has_aux: bool = False):
    """``update(params, opt_state, *args) -> (value, params, opt_state)``: one ``optimizer`` step on
    ``loss_fn(tree, *args)`` (``value``: the loss, or ``(loss, aux)`` with ``has_aux``). ``params`` is a tree or its
    :class:`Flat` form (then ``opt_state`` is packed alike, :class:`LoopCarry`)."""

    def update(params, opt_state, *args):
        value, grads = jax.value_and_grad(lambda p: loss_fn(_tree(p), *args), has_aux=has_aux)(params)
        updates, opt_state = optimizer.update(grads, opt_state, params)
        return value, optax.apply_updates(params, updates), opt_state

    return update


def _index(tree, i):
    return jax.tree.map(lambda x: x[i], tree)


class LoopCarry:
    """The form in which parameters and their optimiser states are carried through a minibatch loop in
    ``layout``; ``pack`` / ``unpack`` convert one network, ``pack_stack`` / ``unpack_stack`` a stack along a
    leading axis, ``update_stack`` steps every network of a packed stack."""

    def __init__(self, layout: str):
        if layout not in LAYOUTS:
            raise ValueError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
        self.flat = layout == "columns"

    def pack(self, params, opt_state):
        return to_flat(params, opt_state) if self.flat else (params, opt_state)

    def unpack(self, params, opt_state):
        return from_flat(params, opt_state) if self.flat else (params, opt_state)

    def pack_stack(self, params, opt_state):
        if not self.flat:
            return params, opt_state
        n = jax.tree.leaves(params)[0].shape[0]
        pairs = [to_flat(_index(params, k), _index(opt_state, k)) for k in range(n)]
        return tuple(p for p, _ in pairs), tuple(o for _, o in pairs)

    def unpack_stack(self, params, opt_state):
        if not self.flat:
            return params, opt_state
        pairs = [from_flat(p, o) for p, o in zip(params, opt_state)]
        stack = lambda *a: jnp.stack(a)
        return jax.tree.map(stack, *(p for p, _ in pairs)), jax.tree.map(stack, *(o for _, o in pairs))

    def update_stack(self, update: Callable, params, opt_state, mapped: tuple = (), shared: tuple = ()):
        """``update`` (a :func:`gradient_update_fn`) on every network of a packed stack: network ``k`` gets
        ``x[k]`` of each array in ``mapped`` and all of ``shared``. Returns ``(values [k, ...], params, opt)``."""
        if not self.flat:
            in_axes = (0, 0) + (0,) * len(mapped) + (None,) * len(shared)
            return jax.vmap(update, in_axes=in_axes)(params, opt_state, *mapped, *shared)
        outs = [update(params[k], opt_state[k], *(x[k] for x in mapped), *shared) for k in range(len(params))]
        return (jnp.stack([o[0] for o in outs]), tuple(o[1] for o in outs), tuple(o[2] for o in outs))
