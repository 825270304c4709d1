"""Tests for jaxsmarl.stackelberg against brute-force enumeration in plain Python (paper eq. p14)."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxsmarl import stackelberg_equilibrium, stackelberg_values

# ----------------------------------------------------------------------------------------------------
# Independent truth: plain-Python enumeration of one state at a time.
# ----------------------------------------------------------------------------------------------------


def _pick(options, d, infeasible, last):
    """options: list over actions of (q, g). Returns the chosen action index (scan with strict >)."""
    order = list(range(len(options)))
    if last:
        order.reverse()  # scanning from the end with strict '>' keeps the highest index among ties
    feasible = [a for a in order if options[a][1] <= d]
    if feasible:
        cands, key = feasible, (lambda a: (options[a][0],))
    elif infeasible == "argmax":
        cands, key = order, (lambda a: (options[a][0],))
    else:  # min_cost: lowest cost, then highest q
        cands, key = order, (lambda a: (-options[a][1], options[a][0]))
    best = None
    for a in cands:
        if best is None or key(a) > key(best):
            best = a
    return best


def ref_stackelberg(qs, gs, ds, infeasible="min_cost", last=False):
    """Backward induction by recursion: every agent best-responds to every prefix above it."""
    k = len(qs)
    shape = qs[0].shape

    def solve(prefix):
        i = len(prefix)
        if i == k:
            return ()
        conts, options = [], []
        for a in range(shape[i]):
            cont = solve(prefix + (a,))
            joint = prefix + (a,) + cont
            conts.append(cont)
            options.append((float(qs[i][joint]), float(gs[i][joint])))
        a = _pick(options, float(ds[i]), infeasible, last)
        return (a,) + conts[a]

    return solve(())


def ref_authors(qs, gs, ds, infeasible="min_cost", last=True):
    """The authors' loops (docs/algorithms.md, CSQ): a_L outer, a_F inner, '>=' keeps the last maximiser.

    Generalised top-down: agent i scans all completions (a_i, ..., a_k) of the chosen prefix in loop order.
    """
    k = len(qs)
    shape = qs[0].shape
    better = (lambda new, old: new >= old) if last else (lambda new, old: new > old)
    prefix = ()
    for i in range(k):
        comps = list(itertools.product(*[range(n) for n in shape[i:]]))
        q = {c: float(qs[i][prefix + c]) for c in comps}
        g = {c: float(gs[i][prefix + c]) for c in comps}
        best = None
        for c in comps:  # feasible best
            if g[c] <= ds[i] and (best is None or better(q[c], q[best])):
                best = c
        if best is None:  # backup
            key = (lambda c: (q[c],)) if infeasible == "argmax" else (lambda c: (-g[c], q[c]))
            for c in comps:
                if best is None or better(key(c), key(best)):
                    best = c
        prefix = prefix + (best[0],)
    return prefix


def ref_batch(fn, qs, gs, ds, **kw):
    k = len(qs)
    batch_shape = qs[0].shape[: qs[0].ndim - k]
    ds = [np.broadcast_to(np.asarray(d, np.float64), batch_shape) for d in ds]
    out = np.zeros(batch_shape + (k,), np.int64)
    for b in np.ndindex(*batch_shape):
        out[b] = fn([q[b] for q in qs], [g[b] for g in gs], [d[b] for d in ds], **kw)
    return out


# ----------------------------------------------------------------------------------------------------
# Property tests.
# ----------------------------------------------------------------------------------------------------


@st.composite
def games(draw):
    k = draw(st.integers(1, 3))
    max_a = 3 if k == 3 else 5
    action_shape = tuple(draw(st.lists(st.integers(1, max_a), min_size=k, max_size=k)))
    batch_shape = tuple(draw(st.lists(st.integers(1, 6), min_size=0, max_size=2)))
    shape = batch_shape + action_shape
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    dtype = draw(st.sampled_from([np.float32, np.int32]))
    q_hi = draw(st.integers(0, 3))  # small integer ranges force ties
    g_hi = draw(st.integers(0, 3))
    qs = [rng.integers(-q_hi, q_hi + 1, shape).astype(dtype) for _ in range(k)]
    gs = [rng.integers(0, g_hi + 1, shape).astype(dtype) for _ in range(k)]
    ds = []
    for _ in range(k):
        # -1: every row infeasible at that level; g_hi: everything feasible; in between: partial.
        if batch_shape and draw(st.booleans()):
            ds.append(rng.integers(-1, g_hi + 1, batch_shape[-1:]).astype(np.float32))  # broadcast
        else:
            ds.append(float(draw(st.integers(-1, g_hi))))
    return qs, gs, ds


CONFIGS = st.tuples(
    st.sampled_from(["stackelberg", "authors"]),
    st.sampled_from(["min_cost", "argmax"]),
    st.sampled_from(["first", "last"]),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(game=games(), config=CONFIGS)
def test_matches_brute_force(game, config):
    qs, gs, ds = game
    leader_rule, infeasible, tie_break = config
    got = np.asarray(
        stackelberg_equilibrium(qs, gs, ds, infeasible=infeasible, leader_rule=leader_rule, tie_break=tie_break)
    )
    ref = ref_stackelberg if leader_rule == "stackelberg" else ref_authors
    want = ref_batch(ref, qs, gs, ds, infeasible=infeasible, last=tie_break == "last")
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, want)
    # The values helper is a plain gather at the returned joint action.
    vals = stackelberg_values(list(qs), got)
    for q, v in zip(qs, vals):
        for b in np.ndindex(*want.shape[:-1]):
            assert v[b] == q[b + tuple(want[b])]


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), batch=st.integers(1, 8))
def test_continuous_values_two_levels(seed, batch):
    """Real-valued (tie-free) 5x5 games, the CSQ shape, with the documented defaults."""
    rng = np.random.default_rng(seed)
    qs = [rng.normal(size=(batch, 5, 5)).astype(np.float32) for _ in range(2)]
    gs = [rng.normal(size=(batch, 5, 5)).astype(np.float32) for _ in range(2)]
    ds = [rng.normal(size=(batch,)).astype(np.float32), 0.3]
    got = np.asarray(stackelberg_equilibrium(qs, gs, ds))
    np.testing.assert_array_equal(got, ref_batch(ref_stackelberg, qs, gs, ds))
    got = np.asarray(stackelberg_equilibrium(qs, gs, ds, leader_rule="authors", infeasible="argmax"))
    np.testing.assert_array_equal(got, ref_batch(ref_authors, qs, gs, ds, infeasible="argmax"))


# ----------------------------------------------------------------------------------------------------
# A hand-made game whose Stackelberg outcome is not its Nash equilibrium.
# ----------------------------------------------------------------------------------------------------

# Leader = row (U=0, D=1), follower = column (L=0, R=1). Payoffs (Q1, Q2):
#            L        R
#   U     (1, 0)   (3, 2)
#   D     (2, 1)   (4, 0)
# Nash: D strictly dominates U for the row player (2 > 1, 4 > 3); against D the column player takes
# L (1 > 0). So the unique pure Nash equilibrium is (D, L) with payoffs (2, 1); (U, R) is not Nash
# because the row player would deviate to D (4 > 3). (No mixed NE either, D being strictly dominant.)
# Stackelberg: the leader commits. U -> follower plays R (2 > 0) -> leader gets 3;
# D -> follower plays L (1 > 0) -> leader gets 2. So the Stackelberg outcome is (U, R) with (3, 2).
Q1 = np.array([[1.0, 3.0], [2.0, 4.0]])
Q2 = np.array([[0.0, 2.0], [1.0, 0.0]])
ZERO = np.zeros((2, 2))


def _pure_nash(q1, q2):
    return [
        (a1, a2)
        for a1 in range(2)
        for a2 in range(2)
        if q1[a1, a2] >= q1[:, a2].max() and q2[a1, a2] >= q2[a1, :].max()
    ]


def test_matrix_game_stackelberg_differs_from_nash():
    assert _pure_nash(Q1, Q2) == [(1, 0)]  # (D, L)
    eq = np.asarray(stackelberg_equilibrium([Q1, Q2], [ZERO, ZERO], [0.0, 0.0]))
    assert tuple(eq) == (0, 1)  # (U, R)
    v1, v2 = stackelberg_values([Q1, Q2], eq)
    assert (float(v1), float(v2)) == (3.0, 2.0)  # the leader gains over its Nash payoff 2


def test_matrix_game_constraints_and_authors_rule():
    # Leader's cost at (U, R) exceeds d1: U is unsafe given the follower's reply, so the leader takes D.
    g1 = np.array([[0.0, 1.0], [0.0, 0.0]])
    assert tuple(np.asarray(stackelberg_equilibrium([Q1, Q2], [g1, ZERO], [0.5, 0.5]))) == (1, 0)
    # Follower's cost at (U, R) exceeds d2: BR(U) = L, so U is worth 1 < 2 to the leader: (D, L).
    g2 = np.array([[0.0, 1.0], [0.0, 0.0]])
    assert tuple(np.asarray(stackelberg_equilibrium([Q1, Q2], [ZERO, g2], [0.5, 0.5]))) == (1, 0)
    # The authors' max-max leader rule chases the best pair for itself, (D, R) = 4, then the follower
    # best-responds to D with L: it lands on the Nash outcome, not the Stackelberg one.
    eq = stackelberg_equilibrium([Q1, Q2], [ZERO, ZERO], [0.0, 0.0], leader_rule="authors")
    assert tuple(np.asarray(eq)) == (1, 0)


def test_infeasible_rules_and_ties():
    q = np.array([[5.0, 1.0, 1.0, 3.0]])  # single level, one state
    g = np.array([[9.0, 2.0, 2.0, 7.0]])
    # Nothing feasible (d = 1): min_cost takes cost 2 (actions 1, 2 tie on Q too) -> lowest index 1.
    assert int(stackelberg_equilibrium([q], [g], [1.0])[0, 0]) == 1
    assert int(stackelberg_equilibrium([q], [g], [1.0], tie_break="last")[0, 0]) == 2
    # argmax ignores the costs.
    assert int(stackelberg_equilibrium([q], [g], [1.0], infeasible="argmax")[0, 0]) == 0
    # All equal: first / last index.
    flat = np.zeros((1, 4))
    assert int(stackelberg_equilibrium([flat], [flat], [0.0])[0, 0]) == 0
    assert int(stackelberg_equilibrium([flat], [flat], [0.0], tie_break="last")[0, 0]) == 3
    # min_cost: equal lowest costs, ties to the higher Q.
    g2 = np.array([[1.0, 1.0, 0.0, 0.0]])
    q2 = np.array([[9.0, 9.0, 1.0, 2.0]])
    assert int(stackelberg_equilibrium([q2], [g2], [-1.0])[0, 0]) == 3


def test_minus_inf_values_stay_feasible():
    q = np.array([[-np.inf, 7.0, -np.inf]], np.float32)
    g = np.array([[0.0, 1.0, 0.0]], np.float32)
    assert int(stackelberg_equilibrium([q], [g], [0.5])[0, 0]) == 0
    assert int(stackelberg_equilibrium([q], [g], [0.5], tie_break="last")[0, 0]) == 2


@pytest.mark.parametrize("tie_break", ["first", "last"])
def test_nan_gives_a_valid_index(tie_break):
    nan = np.full((3, 4, 4), np.nan, np.float32)
    eq = np.asarray(stackelberg_equilibrium([nan, nan], [nan, nan], [0.0, 0.0], tie_break=tie_break))
    assert ((eq >= 0) & (eq < 4)).all()


# ----------------------------------------------------------------------------------------------------
# Transformations and precision.
# ----------------------------------------------------------------------------------------------------


def _random_game(seed, batch=16, a=(5, 5), dtype=np.float32):
    rng = np.random.default_rng(seed)
    shape = (batch,) + a
    qs = [rng.integers(-3, 4, shape).astype(dtype) for _ in a]
    gs = [rng.integers(0, 3, shape).astype(dtype) for _ in a]
    ds = [rng.integers(-1, 3, (batch,)).astype(dtype) for _ in a]
    return qs, gs, ds


@pytest.mark.parametrize("leader_rule", ["stackelberg", "authors"])
def test_jit_vmap_match_batched(leader_rule):
    qs, gs, ds = _random_game(0)

    def one(q1, q2, g1, g2, d1, d2):
        eq = stackelberg_equilibrium([q1, q2], [g1, g2], [d1, d2], leader_rule=leader_rule)
        return eq, stackelberg_values((q1, q2), eq)

    eq_v, (v1, v2) = jax.jit(jax.vmap(one))(*qs, *gs, *ds)
    eq_b = stackelberg_equilibrium(qs, gs, ds, leader_rule=leader_rule)
    np.testing.assert_array_equal(np.asarray(eq_v), np.asarray(eq_b))
    ref = ref_stackelberg if leader_rule == "stackelberg" else ref_authors
    np.testing.assert_array_equal(np.asarray(eq_b), ref_batch(ref, qs, gs, ds))
    np.testing.assert_array_equal(np.asarray(v1), stackelberg_values(qs[0], eq_b))
    # Thresholds can be traced too.
    eq_j = jax.jit(lambda q, g, d: stackelberg_equilibrium(q, g, d, leader_rule=leader_rule))(qs, gs, ds)
    np.testing.assert_array_equal(np.asarray(eq_j), np.asarray(eq_b))


def test_x64():
    with jax.enable_x64(True):
        rng = np.random.default_rng(1)
        qs = [rng.normal(size=(8, 4, 3)) for _ in range(2)]
        # values that differ only beyond float32 precision: x64 must separate them
        qs[1][..., 0] = 1.0
        qs[1][..., 1] = 1.0 + 1e-12
        qs[1][..., 2] = 1.0 - 1e-12
        gs = [np.zeros((8, 4, 3)), np.zeros((8, 4, 3))]
        eq = stackelberg_equilibrium(qs, gs, [0.0, 0.0])
        assert eq.dtype == jnp.int32
        np.testing.assert_array_equal(np.asarray(eq[..., 1]), 1)
        np.testing.assert_array_equal(np.asarray(eq), ref_batch(ref_stackelberg, qs, gs, [0.0, 0.0]))
        v = stackelberg_values(jnp.asarray(qs[1]), eq)
        assert v.dtype == jnp.float64
        np.testing.assert_array_equal(np.asarray(v), 1.0 + 1e-12)


def test_values_pytree():
    qs, gs, _ = _random_game(3, batch=4, a=(2, 3, 4))
    eq = np.stack([np.array([0, 1, 1, 0]), np.array([2, 0, 1, 2]), np.array([3, 0, 2, 1])], -1)
    out = stackelberg_values({"q": qs[0], "g": gs}, eq)
    for b in range(4):
        assert out["q"][b] == qs[0][(b,) + tuple(eq[b])]
        assert out["g"][2][b] == gs[2][(b,) + tuple(eq[b])]


# ----------------------------------------------------------------------------------------------------
# Validation.
# ----------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"infeasible": "clip"}, "infeasible='clip'.*'min_cost', 'argmax'"),
        ({"leader_rule": "nash"}, "leader_rule='nash'.*'stackelberg', 'authors'"),
        ({"tie_break": "random"}, "tie_break='random'.*'first', 'last'"),
    ],
)
def test_unknown_options(kwargs, match):
    with pytest.raises(ValueError, match=match):
        stackelberg_equilibrium([Q1, Q2], [ZERO, ZERO], [0.0, 0.0], **kwargs)


def test_shape_and_count_errors():
    with pytest.raises(ValueError, match="thresholds has 1 entries.*q_values has 2"):
        stackelberg_equilibrium([Q1, Q2], [ZERO, ZERO], [0.0])
    with pytest.raises(ValueError, match="cost_values has 3 entries"):
        stackelberg_equilibrium([Q1, Q2], [ZERO, ZERO, ZERO], [0.0, 0.0])
    with pytest.raises(ValueError, match=r"cost_values\[1\] has shape \(2, 3\), expected \(2, 2\)"):
        stackelberg_equilibrium([Q1, Q2], [ZERO, np.zeros((2, 3))], [0.0, 0.0])
    with pytest.raises(ValueError, match=r"q_values\[1\] has shape"):
        stackelberg_equilibrium([np.zeros((4, 2, 2)), np.zeros((3, 2, 2))], [np.zeros((4, 2, 2))] * 2, [0, 0])
    with pytest.raises(ValueError, match=r"thresholds\[0\] has shape \(3,\).*batch shape \(4,\)"):
        stackelberg_equilibrium([np.zeros((4, 2, 2))] * 2, [np.zeros((4, 2, 2))] * 2, [np.zeros(3), 0.0])
    with pytest.raises(ValueError, match="fewer than k=3 axes"):
        stackelberg_equilibrium([Q1, Q1, Q1], [Q1, Q1, Q1], [0, 0, 0])
    with pytest.raises(ValueError, match="q_values is empty"):
        stackelberg_equilibrium([], [], [])
    with pytest.raises(ValueError, match="does not match equilibrium"):
        stackelberg_values(np.zeros((3, 2, 2)), np.zeros((4, 2), np.int32))
