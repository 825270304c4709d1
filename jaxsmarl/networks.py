"""Centralized joint-action critics for the Stackelberg algorithms (paper eqs. q_value / cost_value).

Each agent i owns a reward critic ``Q_i(s, a1, a2)`` and a cost critic ``G_i(s, a1, a2)``. As in the authors'
code (``Critic_Discrete`` / ``Cost_Discrete``, docs/algorithms.md, CSQ) a critic is an MLP (64-64-64, ReLU, linear
output) on ``concat(o_i, onehot(a1), onehot(a2))`` where ``o_i`` is the agent's own observation.

The networks of all agents and kinds are stored as ONE parameter pytree with leading axes
``[n_agents, n_kinds]`` (e.g. ``[2, 2]`` = {leader, follower} x {Q, G}); evaluation contracts over those axes with
batched matrix products (einsums over the stacked weights), which XLA:CPU runs much faster than nested vmaps.
:func:`joint_values` evaluates every joint action
``A1 x ... x Ak`` in one forward pass; :func:`values_at` evaluates one given joint action.

MADDPG's critics (continuous actions) are the same networks on ``concat(s, a1, a2)``: :func:`critic_values` (the
stacked einsums) and :func:`critic_values_columns` (each network on its own in the column layout of
:mod:`jaxsmarl.columns`), built for a layout by :func:`make_critic_stack` (docs/design.md, networks and layouts).
:class:`Dense` names its layers by :func:`layer_name`, which the functions above read.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np

from jaxsmarl import columns
from jaxsmarl.layout import layout as current_layout
from jaxsmarl.network import Network

__all__ = ["Dense", "layer_name", "JointActionMLP", "joint_action_grid", "joint_onehot", "init_stacked",
           "joint_values", "values_at", "critic_values", "critic_values_columns", "make_critic_stack",
           "soft_update"]


def layer_name(i: int) -> str:
    """The parameter name of the ``i``-th :class:`Dense` layer of :class:`JointActionMLP` and
    :class:`jaxsmarl.actor.Actor` (the output layer is the last); the names flax's automatic naming gave, so that
    trees written before stay valid."""
    return f"_Dense_{i}"


class Dense(nn.Module):
    """Dense layer with a choice of initialisation ("torch": the authors' PyTorch default, "lecun": flax's)."""

    features: int
    init_scheme: str = "torch"

    @nn.compact
    def __call__(self, x):
        fan_in = x.shape[-1]
        if self.init_scheme == "torch":
            bound = 1.0 / math.sqrt(fan_in)
            # the default float: float32, or float64 under jax_enable_x64 (parity runs)
            k_init = lambda key, shape: jax.random.uniform(key, shape, jnp.zeros(()).dtype, -bound, bound)
            b_init = k_init
        else:
            k_init, b_init = nn.initializers.lecun_normal(), nn.initializers.zeros
        kernel = self.param("kernel", k_init, (fan_in, self.features))
        bias = self.param("bias", b_init, (self.features,))
        return x @ kernel + bias


class JointActionMLP(nn.Module):
    """Scalar critic ``f(o, onehot(a1), ..., onehot(ak))``: MLP ``hidden`` with ReLU, linear scalar output."""

    hidden: Sequence[int] = (64, 64, 64)
    init_scheme: str = "torch"

    @nn.compact
    def __call__(self, obs: jax.Array, joint_onehot: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, joint_onehot], axis=-1)
        for i, h in enumerate(self.hidden):
            x = nn.relu(Dense(h, self.init_scheme, name=layer_name(i))(x))
        return Dense(1, self.init_scheme, name=layer_name(len(self.hidden)))(x)[..., 0]


def joint_action_grid(num_actions: Sequence[int]) -> np.ndarray:
    """One-hot encodings of every joint action in row-major order: ``[prod(A), sum(A)]`` float32."""
    num_actions = tuple(int(a) for a in num_actions)
    idx = np.stack(np.meshgrid(*[np.arange(a) for a in num_actions], indexing="ij"), -1).reshape(-1, len(num_actions))
    return joint_onehot(idx, num_actions)


def joint_onehot(actions, num_actions: Sequence[int]):
    """``[..., k]`` int actions -> ``[..., sum(A)]`` concatenated one-hots (numpy in, numpy out; jax in, jax out)."""
    xp = np if isinstance(actions, np.ndarray) else jnp
    parts = [(actions[..., i : i + 1] == xp.arange(a)).astype(xp.float32) for i, a in enumerate(num_actions)]
    return xp.concatenate(parts, axis=-1)


def init_stacked(module: nn.Module, key: jax.Array, obs_dim: int, num_actions: Sequence[int], shape=(2, 2)):
    """Independently initialised parameters for ``prod(shape)`` critics, stacked with leading axes ``shape``."""
    n = math.prod(shape)
    obs = jnp.zeros((1, obs_dim), jnp.float32)
    act = jnp.zeros((1, sum(num_actions)), jnp.float32)
    params = jax.vmap(lambda k: module.init(k, obs, act))(jax.random.split(key, n))
    return jax.tree.map(lambda x: x.reshape(tuple(shape) + x.shape[1:]), params)


def _layers(params) -> list:
    """The stacked Dense layers of :class:`JointActionMLP` parameters, input to output."""
    p = params["params"]
    return [p[layer_name(i)] for i in range(len(p))]


def _hidden_and_out(h: jax.Array, layers: list) -> jax.Array:
    """Layers 2..L of the stacked MLPs: ``h`` ``[n, k, R, H]`` (after the first ReLU) -> ``[n, k, R]``."""
    for layer in layers[1:-1]:
        h = nn.relu(jnp.einsum("nkrh,nkho->nkro", h, layer["kernel"]) + layer["bias"][:, :, None])
    out = layers[-1]
    return jnp.einsum("nkrh,nkho->nkro", h, out["kernel"])[..., 0] + out["bias"][:, :, None, 0]


def joint_values(params, obs: jax.Array, num_actions: Sequence[int]) -> jax.Array:
    """All critics over all joint actions in one batched pass.

    Same function as :class:`JointActionMLP` applied to ``concat(o_i, onehot(a))`` for every joint action, but
    the first layer is split: ``W [o; onehot] = W_o o + W_a onehot`` (``W_a onehot`` is one row per action), so
    the observation part is computed once per state and the joint-action grid costs one broadcast add.

    Args:
      params: stacked ``[n_agents, n_kinds, ...]`` parameters (:func:`init_stacked`).
      obs: ``[..., n_agents, obs_dim]``; agent i's critics see ``obs[..., i, :]``.
    Returns:
      ``[..., n_agents, n_kinds, A1, ..., Ak]``.
    """
    grid = jnp.asarray(joint_action_grid(num_actions))  # [J, sum A]
    batch, (n, d) = obs.shape[:-2], obs.shape[-2:]
    o = obs.reshape((-1, n, d))  # [R, n, D]
    layers = _layers(params)
    w, b = layers[0]["kernel"], layers[0]["bias"]  # [n, k, D + sum A, H], [n, k, H]
    k, hdim = w.shape[1], w.shape[-1]
    h_obs = jnp.einsum("rnd,nkdh->nkrh", o, w[:, :, :d])  # [n, k, R, H]
    h_act = jnp.einsum("jd,nkdh->nkjh", grid, w[:, :, d:]) + b[:, :, None]  # [n, k, J, H]
    h = nn.relu(h_obs[:, :, :, None] + h_act[:, :, None])  # [n, k, R, J, H]
    out = _hidden_and_out(h.reshape((n, k, -1, hdim)), layers)  # [n, k, R * J]
    out = jnp.moveaxis(out.reshape((n, k, o.shape[0], grid.shape[0])), 2, 0)  # [R, n, k, J]
    return out.reshape(batch + (n, k) + tuple(num_actions))


def values_at(params, obs: jax.Array, actions: jax.Array, num_actions: Sequence[int]) -> jax.Array:
    """All critics at one joint action each: obs ``[..., n_agents, obs_dim]``, actions ``[..., k]`` ->
    ``[..., n_agents, n_kinds]``."""
    batch, (n, d) = obs.shape[:-2], obs.shape[-2:]
    o = obs.reshape((-1, n, d))
    onehot = joint_onehot(actions.reshape((-1, actions.shape[-1])), num_actions)  # [R, sum A]
    layers = _layers(params)
    w, b = layers[0]["kernel"], layers[0]["bias"]
    h = jnp.einsum("rnd,nkdh->nkrh", o, w[:, :, :d]) + jnp.einsum("ra,nkah->nkrh", onehot, w[:, :, d:])
    out = _hidden_and_out(nn.relu(h + b[:, :, None]), layers)  # [n, k, R]
    return jnp.moveaxis(out, 2, 0).reshape(batch + out.shape[:2])


def critic_values(params, x: jax.Array) -> jax.Array:
    """Stacked critics (``[n, K, ...]`` :class:`JointActionMLP` parameters) on per-agent inputs ``x``
    ``[R, n, D_in]`` (agent i's critics read ``x[:, i]``) -> ``[R, n, K]``."""
    layers = _layers(params)
    h = jnp.einsum("rnd,nkdh->nkrh", x, layers[0]["kernel"]) + layers[0]["bias"][:, :, None]
    for layer in layers[1:]:
        h = jnp.einsum("nkrh,nkho->nkro", nn.relu(h), layer["kernel"]) + layer["bias"][:, :, None]
    return jnp.moveaxis(h[..., 0], 2, 0)


def critic_values_columns(params, x: jax.Array) -> jax.Array:
    """:func:`critic_values` (the same function) with each critic run on its own in the column layout of
    :mod:`jaxsmarl.columns`: faster reverse-mode gradients on XLA:CPU, no forward-mode derivative."""
    layers = _layers(params)
    n, k = layers[0]["bias"].shape[:2]
    out = []
    for i in range(n):
        xt = x[:, i].T  # [D_in, R]
        for j in range(k):
            net = [{name: w[i, j] for name, w in layer.items()} for layer in layers]
            h = columns.dense(net[0], xt)
            for layer in net[1:]:
                h = columns.dense(layer, nn.relu(h))
            out.append(h[0])
    return jnp.stack(out, axis=-1).reshape((x.shape[0], n, k))


def make_critic_stack(obs_dim: int, num_actions: Sequence[int], hidden: Sequence[int] = (64, 64, 64),
                      init_scheme: str = "torch", shape=(2, 2)) -> Network:
    """A ``shape`` stack of :class:`JointActionMLP` critics on ``obs_dim + sum(num_actions)`` inputs as a
    :class:`jaxsmarl.network.Network` in the layout of :func:`jaxsmarl.layout.layout`: ``init(key)`` (
    :func:`init_stacked`), ``apply`` = :func:`critic_values`, ``apply_update`` its column form
    (:func:`critic_values_columns`) in the column layout."""
    module = JointActionMLP(hidden=tuple(hidden), init_scheme=init_scheme)
    lay = current_layout()
    init = lambda key: init_stacked(module, key, obs_dim, num_actions, shape=shape)
    return Network(lay, init, critic_values, critic_values_columns if lay == "columns" else critic_values)


def soft_update(target, online, tau: float):
    """Polyak averaging ``theta' <- (1 - tau) theta' + tau theta`` (Algorithm 1, target update with rho = 1 - tau)."""
    return jax.tree.map(lambda t, o: (1.0 - tau) * t + tau * o, target, online)
