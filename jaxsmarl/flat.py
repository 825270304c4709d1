"""A network's parameters and its optimiser state as single vectors, for the minibatch loops of the column layout
(one Adam step over one vector instead of one per parameter array); :mod:`jaxsmarl.gradients` packs and unpacks
them."""

from __future__ import annotations

from typing import Callable

import flax.struct
import jax
from jax.flatten_util import ravel_pytree

__all__ = ["Flat", "to_flat", "from_flat"]


@flax.struct.dataclass
class Flat:
    """A parameter tree raveled into one vector (``jax.flatten_util.ravel_pytree``), ``tree()`` to use it.

    Carried through the minibatch loops on XLA:CPU: optax then clips and steps one vector per network (a few
    kernels) instead of each of its arrays (several small kernels each), and the
    gradient arrives as one vector. Same values as the tree form up to summation order (the global norm)."""

    vec: jax.Array
    unravel: Callable = flax.struct.field(pytree_node=False)

    def tree(self):
        return self.unravel(self.vec)


def to_flat(params, opt_state):
    """``(Flat(params), opt_state)`` with every parameter-shaped part of ``opt_state`` (Adam's moments) a
    :class:`Flat` too; :func:`from_flat` is the inverse."""
    vec, unravel = ravel_pytree(params)
    treedef = jax.tree.structure(params)
    is_params = lambda x: isinstance(x, dict) and jax.tree.structure(x) == treedef
    opt = jax.tree.map(lambda s: Flat(ravel_pytree(s)[0], unravel) if is_params(s) else s, opt_state,
                       is_leaf=is_params)
    return Flat(vec, unravel), opt


def from_flat(params: Flat, opt_state):
    """The trees back from :func:`to_flat`'s forms."""
    is_flat = lambda x: isinstance(x, Flat)
    return params.tree(), jax.tree.map(lambda s: s.tree() if is_flat(s) else s, opt_state, is_leaf=is_flat)
