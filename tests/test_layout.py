"""The network layout choice and its override, and the factories' parameter trees against flax's automatic layer
names (the trees that earlier releases wrote into checkpoints)."""

import math

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl.actor import make_actor
from jaxsmarl.gradients import LoopCarry
from jaxsmarl.initializers import orthogonal_init
from jaxsmarl.layout import ENV_VAR, layout
from jaxsmarl.mlp import make_mlp
from jaxsmarl.networks import Dense


def test_layout_from_the_backend_and_the_override(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    assert layout() == ("columns" if jax.default_backend() == "cpu" else "rows")
    for name in ("columns", "rows"):
        monkeypatch.setenv(ENV_VAR, name)
        assert layout() == name
        assert make_mlp(3).layout == name and make_actor(3).layout == name
    monkeypatch.setenv(ENV_VAR, "cols")
    with pytest.raises(ValueError, match="JAXSMARL_LAYOUT must be one of columns, rows"):
        layout()
    with pytest.raises(ValueError, match="layout must be one of columns, rows"):
        LoopCarry("gpu")


class _AutoNamedMLP(nn.Module):
    """The MLP as earlier releases wrote it: flax names its layers (``Dense_j``, ``LayerNorm_j``)."""

    hidden: int
    layer_n: int
    out_dim: int
    feature_norm: bool

    @nn.compact
    def __call__(self, x):
        if self.feature_norm:
            x = nn.LayerNorm(epsilon=1e-5)(x)
        for _ in range(1 + self.layer_n):
            x = nn.Dense(self.hidden, kernel_init=orthogonal_init(math.sqrt(2.0)), bias_init=nn.initializers.zeros)(x)
            x = nn.LayerNorm(epsilon=1e-5)(nn.relu(x))
        return nn.Dense(self.out_dim, kernel_init=orthogonal_init(1.0), bias_init=nn.initializers.zeros)(x)


class _Dense(Dense):
    """The dense layer under its earlier class name, which flax's automatic names (``_Dense_i``) came from."""


class _AutoNamedActor(nn.Module):
    hidden: tuple

    @nn.compact
    def __call__(self, x):
        for h in self.hidden:
            x = nn.relu(_Dense(h)(x))
        return jnp.tanh(_Dense(2)(x))


@pytest.mark.parametrize("layer_n, feature_norm", [(1, True), (2, False)])
def test_factory_trees_are_the_automatically_named_trees(layer_n, feature_norm):
    """The factories name the layers as flax's automatic naming did: the same tree, and the same initial values
    (flax derives each layer's random key from its name), so checkpoints of earlier runs restore."""
    key = jax.random.PRNGKey(3)
    new = make_mlp(5, 16, layer_n, 2, 1.0, feature_norm).init(key)
    old = _AutoNamedMLP(16, layer_n, 2, feature_norm).init(key, jnp.zeros((1, 5)))
    assert jax.tree.structure(new) == jax.tree.structure(old)
    for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(old)):
        np.testing.assert_array_equal(a, b)
    new = make_actor(4, (8, 8), action_dim=2).init(key)
    old = _AutoNamedActor((8, 8)).init(key, jnp.zeros((1, 4)))
    assert jax.tree.structure(new) == jax.tree.structure(old)
    for a, b in zip(jax.tree.leaves(new), jax.tree.leaves(old)):
        np.testing.assert_array_equal(a, b)
