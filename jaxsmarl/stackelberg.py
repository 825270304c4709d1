"""Batched constrained Stackelberg equilibrium selection over a joint-action grid.

Paper equation (p14) and Algorithm 1 (CSQ): for the next state s' the target joint action is

    BR(a1) = argmax_{a2 : G2(a1, a2) <= d2} Q2(a1, a2)                 (follower best response)
    a1*    = argmax_{a1 : G1(a1, BR(a1)) <= d1} Q1(a1, BR(a1))         (leader, anticipating BR)
    a2*    = BR(a1*)

and the TD targets (the unlabelled update equations after p14, and Algorithm 1) read
Q_i^targ(s', a1*, a2*) and G_i^targ(s', a1*, a2*): see :func:`stackelberg_values`.
Here every value is a tensor ``[..., A1, A2]`` (critics evaluated on the whole joint-action grid), so the
equilibrium is a masked reduction over the action axes: no loops over the batch or the actions.

The same code handles k levels ``[..., A1, ..., Ak]`` (the paper's vertical multi-level expansion) by
backward induction: agent k best-responds to every prefix (a1..a_{k-1}); agent k-1 maximises its Q over
a_{k-1} given that response, subject to its own constraint evaluated at that response; ... up to agent 1.

Rules fixed here (the paper leaves them open):

* Ties: among equal maxima the LOWEST index wins (``tie_break="first"``, as ``jnp.argmax``). Follower
  ties are broken by index, not in the leader's favour (neither the strong nor the weak SSE convention).
  ``tie_break="last"`` makes the highest index win instead (the authors' ``>=`` loops).
* No feasible action at a level (``infeasible``):
  ``"min_cost"`` (default): take the action with the lowest cost estimate, ties to the highest Q, then the
  index rule; ``"argmax"``: the unconstrained argmax of Q (the authors' "backup").
* ``leader_rule="authors"`` reproduces the rule coded in the authors' CSQ (docs/algorithms.md, CSQ):
  ``a1* = argmax_{a1} max_{a2 : G1(a1,a2) <= d1} Q1(a1, a2)``, a max-max over jointly feasible pairs
  under the leader's own Q1/G1 only (fallback when no pair is feasible: the ``infeasible`` rule applied
  over all pairs), then the follower plays its constrained best response to a1*. For k levels it is
  applied top-down: each agent, given the actions already chosen above it, takes its action from the best
  jointly feasible completion under its own Q/G. Its default tie rule is "last" in the authors' loop order
  (a1 outer, ..., ak inner), which is what their ``>=`` comparisons do.

Hierarchies (``hierarchy=``, :mod:`jaxsmarl.hierarchy`; the paper's multi-agent expansion): the levels are solved
by backward induction as above, last level first; each level responds to every joint action of the levels above
it. A level with one agent is the constrained argmax above. A level with several agents plays a pure-strategy
equilibrium among themselves, found by enumerating the level's joint actions (exact, no iteration): a profile is
an equilibrium when every agent's action is its own constrained best response (the rule above: feasible set,
``infeasible`` fallback, index ties) to the others' actions. The level's joint action is the first profile in the
order: fewest agents not best-responding (0 = an equilibrium) > most agents within their cost limit > highest sum
of the level's Q values > the index rule over the level's joint actions in row-major order (agents in increasing
index). When the level has no pure equilibrium this same order is the fallback: the profile closest to one.

NaN values give a valid index but an otherwise unspecified choice.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

from jaxsmarl.hierarchy import agent_order, is_chain, validate_hierarchy

__all__ = ["stackelberg_equilibrium", "stackelberg_values"]

INFEASIBLE_RULES = ("min_cost", "argmax")
LEADER_RULES = ("stackelberg", "authors")
TIE_BREAKS = ("first", "last")


# ----------------------------------------------------------------------------------------------------
# Masked lexicographic selection along one axis (the one reduction every level uses).
# ----------------------------------------------------------------------------------------------------


def _lowest(dtype) -> jax.Array:
    """A value no larger than any value of ``dtype``."""
    if jnp.issubdtype(dtype, jnp.inexact):
        return jnp.array(-jnp.inf, dtype)
    if jnp.issubdtype(dtype, jnp.bool_):
        return jnp.array(False)
    return jnp.array(jnp.iinfo(dtype).min, dtype)


def _highest(dtype) -> jax.Array:
    """A value no smaller than any value of ``dtype``."""
    if jnp.issubdtype(dtype, jnp.inexact):
        return jnp.array(jnp.inf, dtype)
    if jnp.issubdtype(dtype, jnp.bool_):
        return jnp.array(True)
    return jnp.array(jnp.iinfo(dtype).max, dtype)


def _select(q: jax.Array, g: jax.Array, d: jax.Array, infeasible: str, last: bool) -> jax.Array:
    """Constrained argmax of ``q`` along the last axis subject to ``g <= d``, with the fallback rule.

    One pass (a variadic ``lax.reduce``) under the lexicographic order
    feasible first > [if min_cost: lower cost, among infeasible ones] > higher q > lower (or higher) index.
    If any action is feasible only feasible ones can win; otherwise the fallback order decides. Exact for
    any values, including +-inf (no sentinel arithmetic); with NaNs the index is valid but unspecified.
    ``d`` is already broadcastable to ``g``. Returns int32 indices, the last axis reduced.
    """
    axis = q.ndim - 1
    ok = g <= d
    idx = lax.broadcasted_iota(jnp.int32, q.shape, axis)
    min_cost = infeasible == "min_cost"

    def pick(a, b):
        ok_a, g_a, q_a, i_a = a
        ok_b, g_b, q_b, i_b = b
        win = ok_a & ~ok_b
        tie = ok_a == ok_b
        if min_cost:  # costs rank only infeasible actions
            win = win | (tie & ~ok_a & (g_a < g_b))
            tie = tie & (ok_a | ~((g_a < g_b) | (g_b < g_a)))
        win = win | (tie & (q_a > q_b))
        tie = tie & ~((q_a > q_b) | (q_b > q_a))
        win = win | (tie & ((i_a > i_b) if last else (i_a < i_b)))
        return tuple(lax.select(win, x, y) for x, y in zip(a, b))

    # The identity loses every comparison against a real action (at the latest on the index).
    n = q.shape[axis]
    init = (jnp.array(False), _highest(g.dtype), _lowest(q.dtype), jnp.array(-1 if last else n, jnp.int32))
    return lax.reduce((ok, g, q, idx), init, pick, (axis,))[3]


def _take_last(x: jax.Array, idx: jax.Array) -> jax.Array:
    """``x[..., idx]`` per leading index: ``idx`` has shape ``x.shape[:-1]``."""
    return jnp.take_along_axis(x, idx[..., None], axis=-1)[..., 0]


# ----------------------------------------------------------------------------------------------------
# Solvers (traced; inputs already validated).
# ----------------------------------------------------------------------------------------------------


def _argbest(keys: Sequence[jax.Array], last: bool) -> jax.Array:
    """Index along the last axis of the lexicographic best of ``keys`` (each: higher wins), then the index rule.
    One variadic ``lax.reduce``, exact for any values; int32, the last axis reduced."""
    axis = keys[0].ndim - 1
    n = keys[0].shape[axis]
    idx = lax.broadcasted_iota(jnp.int32, keys[0].shape, axis)

    def pick(a, b):
        win, tie = jnp.zeros(a[0].shape, bool), jnp.ones(a[0].shape, bool)
        for x, y in zip(a[:-1], b[:-1]):
            win = win | (tie & (x > y))
            tie = tie & ~((x > y) | (y > x))
        win = win | (tie & ((a[-1] > b[-1]) if last else (a[-1] < b[-1])))
        return tuple(lax.select(win, x, y) for x, y in zip(a, b))

    init = tuple(_lowest(k.dtype) for k in keys) + (jnp.array(-1 if last else n, jnp.int32),)
    return lax.reduce(tuple(keys) + (idx,), init, pick, (axis,))[-1]


def _level_equilibrium(qs, gs, ds, n_action_axes: int, infeasible: str, last: bool) -> jax.Array:
    """Joint action of the ``s`` agents of one level (module docstring): tensors ``[..., P..., A_1..A_s]``
    (``P``: the actions of the levels above; ``n_action_axes`` = len(P) + s) -> int32 flat index over
    ``A_1..A_s`` (row-major), shape ``[..., P...]``."""
    s = len(qs)
    shape = qs[0].shape
    lead = len(shape) - s
    not_best = jnp.zeros(shape, jnp.int32)
    feasible = jnp.zeros(shape, jnp.int32)
    welfare = jnp.zeros(shape, qs[0].dtype)
    for i in range(s):
        axis = lead + i
        d = jnp.reshape(ds[i], jnp.shape(ds[i]) + (1,) * n_action_axes)
        br = _select(jnp.moveaxis(qs[i], axis, -1), jnp.moveaxis(gs[i], axis, -1), d, infeasible, last)
        best = jnp.expand_dims(br, axis) == lax.broadcasted_iota(jnp.int32, shape, axis)
        not_best = not_best + (~best).astype(jnp.int32)
        feasible = feasible + (gs[i] <= d).astype(jnp.int32)
        welfare = welfare + qs[i]
    flat = lambda x: jnp.reshape(x, shape[:lead] + (-1,))
    return _argbest([flat(-not_best), flat(feasible), flat(welfare)], last)


def _hierarchical(qs, gs, ds, levels, infeasible: str, last: bool) -> jax.Array:
    """Backward induction over the levels of ``levels`` (p14, generalised to any hierarchy; module docstring)."""
    k = len(qs)
    order = agent_order(levels)
    n_batch = qs[0].ndim - k
    if order != tuple(range(k)):  # action axes (and agents) in decision order
        perm = tuple(range(n_batch)) + tuple(n_batch + a for a in order)
        qs = [jnp.transpose(qs[a], perm) for a in order]
        gs = [jnp.transpose(gs[a], perm) for a in order]
        ds = [ds[a] for a in order]
    qs, gs = list(qs), list(gs)
    action_shape = qs[0].shape[n_batch:]
    plan = None  # [..., A_0..A_{p-1}, k-p]: the continuation (positions p..k-1) for every prefix
    end = k
    for level in reversed(levels):  # static loop over the levels, last level first
        p = end - len(level)
        if len(level) == 1:
            d = jnp.reshape(ds[p], jnp.shape(ds[p]) + (1,) * (p + 1))
            choice = _select(qs[p], gs[p], d, infeasible, last)  # [..., A_0..A_{p-1}]: the level's reply
            acts = choice[..., None]
        else:
            choice = _level_equilibrium(qs[p:end], gs[p:end], ds[p:end], end, infeasible, last)
            acts = jnp.stack(jnp.unravel_index(choice, action_shape[p:end]), axis=-1).astype(jnp.int32)
        n_level = math.prod(action_shape[p:end])
        for j in range(p):  # the levels above see the values at this reply
            qs[j] = _take_last(jnp.reshape(qs[j], qs[j].shape[: n_batch + p] + (n_level,)), choice)
            gs[j] = _take_last(jnp.reshape(gs[j], gs[j].shape[: n_batch + p] + (n_level,)), choice)
        if plan is None:
            plan = acts
        else:
            flat_plan = jnp.reshape(plan, plan.shape[: n_batch + p] + (n_level, plan.shape[-1]))
            rest = jnp.take_along_axis(flat_plan, choice[..., None, None], axis=-2)[..., 0, :]
            plan = jnp.concatenate([acts, rest], axis=-1)
        end = p
    if order != tuple(range(k)):  # back to agent order
        plan = plan[..., tuple(order.index(a) for a in range(k))]
    return plan


def _authors(qs, gs, ds, infeasible: str, last: bool) -> jax.Array:
    """The authors' coded rule, top-down: each agent takes the first action of its best feasible completion."""
    k = len(qs)
    action_shape = qs[0].shape[-k:]
    batch_shape = qs[0].shape[:-k]
    prefix = jnp.zeros(batch_shape, jnp.int32)  # flat index of the actions chosen so far
    actions = []
    for i in range(k):
        n_prefix = math.prod(action_shape[:i])
        n_rest = math.prod(action_shape[i + 1 :])
        n_joint = action_shape[i] * n_rest

        def restrict(x, n_prefix=n_prefix, n_joint=n_joint):
            # x[..., prefix, :] flattened: the joint completions (a_i, ..., a_k) after the chosen prefix.
            x = jnp.reshape(x, batch_shape + (n_prefix, n_joint))
            return jnp.take_along_axis(x, prefix[..., None, None], axis=-2)[..., 0, :]

        d = jnp.reshape(ds[i], jnp.shape(ds[i]) + (1,))
        flat = _select(restrict(qs[i]), restrict(gs[i]), d, infeasible, last)  # row-major loop order
        a = (flat // n_rest).astype(jnp.int32)
        actions.append(a)
        prefix = prefix * action_shape[i] + a
    return jnp.stack(actions, axis=-1)


def _authors_chain(qs, gs, ds, levels, infeasible: str, last: bool) -> jax.Array:
    """The authors' rule along a chain in any agent order: solved in decision order, returned in agent order."""
    k = len(qs)
    order = agent_order(levels)
    if order == tuple(range(k)):
        return _authors(qs, gs, ds, infeasible, last)
    n_batch = qs[0].ndim - k
    perm = tuple(range(n_batch)) + tuple(n_batch + a for a in order)
    plan = _authors([jnp.transpose(qs[a], perm) for a in order], [jnp.transpose(gs[a], perm) for a in order],
                    [ds[a] for a in order], infeasible, last)
    return plan[..., tuple(order.index(a) for a in range(k))]


@partial(jax.jit, static_argnames=("levels", "infeasible", "leader_rule", "last"))
def _solve(qs, gs, ds, *, levels, infeasible: str, leader_rule: str, last: bool) -> jax.Array:
    if leader_rule == "authors":
        return _authors_chain(qs, gs, ds, levels, infeasible, last)
    return _hierarchical(qs, gs, ds, levels, infeasible, last)


# ----------------------------------------------------------------------------------------------------
# Public API.
# ----------------------------------------------------------------------------------------------------


def _as_list(name: str, values: Any) -> list:
    if isinstance(values, (str, bytes)) or not hasattr(values, "__len__"):
        raise ValueError(f"{name} must be a sequence with one entry per agent, got {type(values).__name__}")
    return list(values)


def _check_choice(name: str, value: Any, allowed: tuple) -> None:
    if value not in allowed:
        raise ValueError(f"unknown {name}={value!r}; allowed: {', '.join(repr(a) for a in allowed)}")


def stackelberg_equilibrium(
    q_values: Sequence[jax.Array],
    cost_values: Sequence[jax.Array],
    thresholds: Sequence[Any],
    *,
    infeasible: str = "min_cost",
    leader_rule: str = "stackelberg",
    tie_break: str | None = None,
    hierarchy: Any = None,
) -> jax.Array:
    """Pure-strategy constrained Stackelberg equilibrium for a batch of states (paper eq. p14, Alg. 1).

    Args:
      q_values: one reward-value tensor per agent (leader first), each ``[..., A1, ..., Ak]`` over the
        joint action; all ``2k`` tensors must have the same shape. ``k`` is ``len(q_values)``.
      cost_values: one cost-value tensor per agent, same shape.
      thresholds: ``k`` cost limits ``d_i``; scalars or arrays broadcastable to the batch shape ``[...]``.
      infeasible: rule when no action at a level satisfies its constraint: ``"min_cost"`` (lowest cost,
        ties to highest Q, then the index rule) or ``"argmax"`` (unconstrained argmax of Q, as the authors).
      leader_rule: ``"stackelberg"`` (p14, backward induction) or ``"authors"`` (the coded max-max rule,
        see the module docstring).
      tie_break: ``"first"`` (lowest index among equal maxima) or ``"last"`` (highest). ``None`` means
        ``"first"`` for ``"stackelberg"`` and ``"last"`` for ``"authors"`` (their ``>=`` loops).
      hierarchy: who decides before whom, as levels of agent indices (:mod:`jaxsmarl.hierarchy`), e.g.
        ``((0,), (1,), (2,))`` or ``"0,1|2"``; ``None`` is the chain ``0 | 1 | ... | k-1`` (agent 0 leads).
        Value tensors stay in agent-index order whatever the hierarchy. ``"authors"`` needs a chain.

    Returns:
      int32 ``[..., k]``: the equilibrium action of each agent. Jit- and vmap-compatible.

    Raises:
      ValueError: wrong number of cost tensors/thresholds, mismatched shapes, thresholds that do not
        broadcast to the batch shape, an unknown ``infeasible``/``leader_rule``/``tie_break``, an invalid
        hierarchy, or ``"authors"`` with a level of several agents.
    """
    _check_choice("infeasible", infeasible, INFEASIBLE_RULES)
    _check_choice("leader_rule", leader_rule, LEADER_RULES)
    _check_choice("tie_break", tie_break, (None,) + TIE_BREAKS)
    qs = _as_list("q_values", q_values)
    gs = _as_list("cost_values", cost_values)
    ds = _as_list("thresholds", thresholds)
    k = len(qs)
    if k == 0:
        raise ValueError("q_values is empty; need one value tensor per agent (k >= 1)")
    if len(gs) != k:
        raise ValueError(f"cost_values has {len(gs)} entries but q_values has {k}; need one per agent")
    if len(ds) != k:
        raise ValueError(f"thresholds has {len(ds)} entries but q_values has {k}; need one per agent")
    shape = tuple(jnp.shape(qs[0]))
    if len(shape) < k:
        raise ValueError(
            f"q_values[0] has shape {shape} with fewer than k={k} axes; expected [..., A1, ..., A{k}]"
        )
    for name, arrays in (("q_values", qs), ("cost_values", gs)):
        for i, x in enumerate(arrays):
            if tuple(jnp.shape(x)) != shape:
                raise ValueError(
                    f"{name}[{i}] has shape {tuple(jnp.shape(x))}, expected {shape} (the shape of "
                    "q_values[0]); every agent's Q and cost tensor must cover the same batch and joint-action grid"
                )
    if 0 in shape[len(shape) - k :]:
        raise ValueError(f"every agent needs at least one action; action shape is {shape[len(shape) - k:]}")
    batch_shape = shape[: len(shape) - k]
    for i, d in enumerate(ds):
        d_shape = tuple(jnp.shape(d))
        try:
            ok = np.broadcast_shapes(d_shape, batch_shape) == batch_shape
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(
                f"thresholds[{i}] has shape {d_shape}, which does not broadcast to the batch shape {batch_shape}"
            )
    levels = tuple((i,) for i in range(k)) if hierarchy is None else validate_hierarchy(hierarchy, k)
    if leader_rule == "authors" and not is_chain(levels):
        raise ValueError(f"leader_rule='authors' is defined for a chain of single agents (e.g. '0|1|2'); the "
                         f"hierarchy {hierarchy!r} has a level of several agents: use leader_rule='stackelberg'")
    if tie_break is None:
        tie_break = "last" if leader_rule == "authors" else "first"
    return _solve(
        tuple(jnp.asarray(q) for q in qs),
        tuple(jnp.asarray(g) for g in gs),
        tuple(jnp.asarray(d) for d in ds),
        levels=levels,
        infeasible=infeasible,
        leader_rule=leader_rule,
        last=tie_break == "last",
    )


def stackelberg_values(values: Any, equilibrium: jax.Array) -> Any:
    """Gather value tensors at the equilibrium joint action, e.g. ``Q_i^targ(s', a1*, a2*)`` (Alg. 1 targets).

    Args:
      values: an array ``[..., A1, ..., Ak]`` or any pytree (list, tuple, dict) of such arrays.
      equilibrium: int ``[..., k]``, as returned by :func:`stackelberg_equilibrium`.

    Returns:
      The same structure with each array reduced to ``[...]``.
    """
    eq_shape = tuple(jnp.shape(equilibrium))
    if len(eq_shape) < 1:
        raise ValueError("equilibrium must have shape [..., k]; got a scalar")
    k = eq_shape[-1]
    batch_shape = eq_shape[:-1]

    def gather(x):
        x = jnp.asarray(x)
        if x.ndim < k or x.shape[: x.ndim - k] != batch_shape:
            raise ValueError(
                f"value tensor of shape {x.shape} does not match equilibrium of shape {eq_shape}; "
                f"expected {batch_shape} + (A1, ..., A{k})"
            )
        action_shape = x.shape[x.ndim - k :]
        flat = jnp.zeros(batch_shape, jnp.int32)
        for i, n in enumerate(action_shape):  # row-major flat index of the joint action
            flat = flat * n + equilibrium[..., i].astype(jnp.int32)
        x = jnp.reshape(x, batch_shape + (math.prod(action_shape),))
        return _take_last(x, flat)

    return jax.tree.map(gather, values)
