"""The equilibrium for any hierarchy (jaxsmarl/stackelberg.py, ``hierarchy=``) against independent truths:
brute-force backward induction over every subgame in plain Python, matrix games with known pure equilibria, and
the two-agent solver's outputs pinned before hierarchies existed."""

import functools
import itertools

import jax
import numpy as np
import pytest

from jaxsmarl.hierarchy import agent_order, validate_hierarchy
from jaxsmarl.stackelberg import stackelberg_equilibrium
from tests.csq_reference import REFERENCE, SOLVER_RULES, solver_inputs

# ----------------------------------------------------------------------------------------------------------
# Brute force: the documented rule, one state at a time, by enumeration.

def best_response(qs, gs, d, infeasible, last):
    """Constrained argmax over a list of actions: feasible first, [min_cost: lowest cost among infeasible],
    highest q, then the lowest (or highest) index."""
    n = len(qs)
    feasible = [a for a in range(n) if gs[a] <= d]
    if feasible:
        pool = feasible
    elif infeasible == "min_cost":
        lo = min(gs)
        pool = [a for a in range(n) if gs[a] == lo]
    else:
        pool = list(range(n))
    top = max(qs[a] for a in pool)
    winners = [a for a in pool if qs[a] == top]
    return max(winners) if last else min(winners)


def brute_equilibrium(Q, G, d, levels, infeasible="min_cost", last=False):
    """Subgame-perfect outcome by exhaustive recursion: every level, for every history of the levels above,
    enumerates its joint actions; each agent's deviations are answered by the levels below."""
    k = Q[0].ndim
    sizes = Q[0].shape

    @functools.lru_cache(maxsize=None)
    def solve(fixed, li):  # fixed: tuple of (agent, action) chosen above level li -> full joint action
        if li == len(levels):
            joint = dict(fixed)
            return tuple(joint[a] for a in range(k))
        level = levels[li]
        profiles = list(itertools.product(*[range(sizes[a]) for a in level]))

        def outcome(profile):
            return solve(tuple(sorted(fixed + tuple(zip(level, profile)))), li + 1)

        scored = []
        for profile in profiles:
            joint = outcome(profile)
            not_best = feasible = 0
            welfare = np.float32(0)
            for j, a in enumerate(level):
                devs = [outcome(profile[:j] + (x,) + profile[j + 1:]) for x in range(sizes[a])]
                br = best_response([Q[a][t] for t in devs], [G[a][t] for t in devs], d[a], infeasible, last)
                not_best += br != profile[j]
                feasible += bool(G[a][joint] <= d[a])
                welfare = welfare + np.float32(Q[a][joint])
            scored.append((-not_best, feasible, welfare))
        top = max(scored)
        winners = [i for i, sc in enumerate(scored) if sc == top]
        return outcome(profiles[winners[-1] if last else winners[0]])

    return solve((), 0)


def brute_batch(qs, gs, ds, levels, **rule):
    qs, gs, ds = (np.asarray(x) for x in (qs, gs, ds))
    return np.array([brute_equilibrium(qs[:, b], gs[:, b], ds[:, b], levels, **rule) for b in range(qs.shape[1])])


def random_game(seed, sizes, batch, ties=False):
    rng = np.random.default_rng(seed)
    k = len(sizes)
    draw = lambda: rng.normal(size=(k, batch) + tuple(sizes)).astype(np.float32)
    qs, gs = draw(), draw()
    if ties:
        qs, gs = np.round(qs, 0), np.round(gs, 0)
    ds = (0.3 * rng.normal(size=(k, batch))).astype(np.float32)
    return qs, gs, ds


def solve(qs, gs, ds, hierarchy, **rule):
    return np.asarray(stackelberg_equilibrium(list(qs), list(gs), list(ds), hierarchy=hierarchy, **rule))


RULES = [dict(infeasible=i, tie_break=t) for i in ("min_cost", "argmax") for t in ("first", "last")]


def _brute_rule(rule):
    return dict(infeasible=rule["infeasible"], last=rule["tie_break"] == "last")


# ----------------------------------------------------------------------------------------------------------

@pytest.mark.parametrize("hierarchy, sizes, r", [
    ("2|0|1", (3, 4, 2), 0),
    ("3|1|0|2", (2, 3, 3, 2), 1),
    ("0,1|2,3", (2, 3, 3, 2), 2),
    ("0|1,2|3", (3, 2, 3, 2), 3),
    ("0,1,2", (3, 3, 3), 1),
])
def test_sampled_hierarchies_equal_brute_force(hierarchy, sizes, r):
    """A sample of the slow tests below: chains of 3 and 4 levels and levels of several agents, with ties."""
    rule = RULES[r]
    qs, gs, ds = random_game(r, sizes, 16, ties=True)
    want = brute_batch(qs, gs, ds, validate_hierarchy(hierarchy, len(sizes)), **_brute_rule(rule))
    np.testing.assert_array_equal(solve(qs, gs, ds, hierarchy, **rule), want)


@pytest.mark.slow
@pytest.mark.parametrize("hierarchy, sizes", [
    ("0|1|2", (4, 3, 5)),
    ("2|0|1", (3, 4, 2)),
    ("0|1|2|3", (3, 3, 3, 3)),
    ("3|1|0|2", (2, 3, 3, 2)),
])
@pytest.mark.parametrize("ties", [False, True])
def test_chains_equal_brute_force(hierarchy, sizes, ties):
    levels = validate_hierarchy(hierarchy, len(sizes))
    for r, rule in enumerate(RULES):
        qs, gs, ds = random_game(100 * r + len(sizes), sizes, 24, ties)
        got = solve(qs, gs, ds, hierarchy, **rule)
        np.testing.assert_array_equal(got, brute_batch(qs, gs, ds, levels, **_brute_rule(rule)), err_msg=str(rule))


@pytest.mark.slow
@pytest.mark.parametrize("hierarchy, sizes", [
    ("0,1|2", (3, 3, 3)),
    ("2|0,1", (3, 2, 3)),
    ("0,1|2,3", (2, 3, 3, 2)),
    ("0|1,2|3", (3, 2, 3, 2)),
    ("0,1,2", (3, 3, 3)),
    ("0,1", (4, 4)),
])
def test_levels_of_several_agents_equal_brute_force(hierarchy, sizes):
    levels = validate_hierarchy(hierarchy, len(sizes))
    for r, rule in enumerate(RULES):
        for ties in (False, True):
            qs, gs, ds = random_game(7 * r + 3 * ties, sizes, 16, ties)
            got = solve(qs, gs, ds, hierarchy, **rule)
            want = brute_batch(qs, gs, ds, levels, **_brute_rule(rule))
            np.testing.assert_array_equal(got, want, err_msg=f"{rule} ties={ties}")


def test_two_agent_chain_is_todays_solver_bit_for_bit():
    """((0,), (1,)) and the default give the outputs the two-agent solver gave before hierarchies existed."""
    ref = np.load(REFERENCE)
    for k in (2, 3):
        qs, gs, ds = solver_inputs(k)
        for lr, inf, tb in SOLVER_RULES:
            if k == 3 and lr == "authors":  # the authors' rule for an index-order chain is today's code itself
                continue
            want = ref[f"solver/solver_k{k}_{lr}_{inf}_{tb}"]
            for h in (None, tuple((i,) for i in range(k)), "|".join(map(str, range(k)))):
                got = stackelberg_equilibrium(qs, gs, ds, leader_rule=lr, infeasible=inf, tie_break=tb, hierarchy=h)
                np.testing.assert_array_equal(np.asarray(got), want)


def test_reordered_chain_is_the_chain_of_reordered_agents():
    """'1|0' (agent 1 leads) = the default solver on the swapped game, for both leader rules."""
    qs, gs, ds = random_game(5, (5, 5), 64, ties=True)
    swap = lambda x: [np.swapaxes(x[1], 1, 2), np.swapaxes(x[0], 1, 2)]
    for lr in ("stackelberg", "authors"):
        got = solve(qs, gs, ds, "1|0", leader_rule=lr)
        want = np.asarray(stackelberg_equilibrium(swap(qs), swap(gs), [ds[1], ds[0]], leader_rule=lr))[:, ::-1]
        np.testing.assert_array_equal(got, want)


# Matrix games on one level (no constraints unless stated): Q[agent][a0, a1].
def _game(q0, q1, g0=None, g1=None):
    q = np.array([q0, q1], np.float32)[:, None]
    g = np.zeros_like(q) if g0 is None else np.array([g0, g1], np.float32)[:, None]
    return q, g, np.zeros((2, 1), np.float32)


PRISONERS = ([[3, 0], [5, 1]], [[3, 5], [0, 1]])  # 0 cooperate, 1 defect: unique equilibrium (defect, defect)
# A 3x3 game with a unique pure equilibrium (2, 0), found by iterated elimination of dominated actions.
DOMINANCE = ([[1, 0, 2], [0, 1, 1], [3, 2, 4]], [[0, 2, 1], [1, 3, 0], [2, 1, 0]])


@pytest.mark.parametrize("game, want", [(PRISONERS, (1, 1)), (DOMINANCE, (2, 0))])
def test_matrix_games_with_a_unique_pure_equilibrium(game, want):
    q, g, d = _game(*game)
    for rule in RULES:
        assert tuple(solve(q, g, d, "0,1", **rule)[0]) == want
    # the same game below a leader (agent 0, three actions) whose value does not depend on the followers: the
    # level still plays its equilibrium and the leader its best action
    grid = (3,) + q.shape[2:]
    lead = np.broadcast_to(np.arange(3, dtype=np.float32)[:, None, None], grid)
    follow = [np.broadcast_to(q[i, 0][None], grid) for i in range(2)]
    q3 = np.stack([lead] + follow)[:, None]
    z = np.zeros_like(q3)
    assert tuple(solve(q3, z, np.zeros((3, 1), np.float32), "0|1,2")[0]) == (2,) + want


def test_constraints_change_the_equilibrium():
    """Defecting costs agent 0 more than its limit: its constrained best response is always to cooperate, and the
    unique constrained equilibrium is (cooperate, defect)."""
    q, g, d = _game(*PRISONERS, g0=[[0, 0], [1, 1]], g1=[[0, 0], [0, 0]])
    assert tuple(solve(q, g, d, "0,1")[0]) == (0, 1)
    assert tuple(solve(q, g, d, "0,1", infeasible="argmax")[0]) == (0, 1)


def test_equilibrium_selection_and_fallback():
    # stag hunt: equilibria (0, 0) worth 4 + 4 and (1, 1) worth 2 + 2; the higher sum of Q wins
    q, g, d = _game([[4, 0], [3, 2]], [[4, 3], [0, 2]])
    assert tuple(solve(q, g, d, "0,1")[0]) == (0, 0)
    # ... unless it breaks a cost limit: more agents within their limits wins first
    q, g, d = _game([[4, 0], [3, 2]], [[4, 3], [0, 2]], g0=[[0.5, 0], [0, 0]], g1=[[0, 0], [0, 0]])
    d = np.array([[1.0], [0.0]], np.float32)  # agent 0 feasible everywhere: still (0, 0)
    assert tuple(solve(q, g, d, "0,1")[0]) == (0, 0)
    # matching pennies: no pure equilibrium; every profile has one agent not best-responding and the same sum,
    # so the index rule decides
    q, g, d = _game([[1, -1], [-1, 1]], [[-1, 1], [1, -1]])
    assert tuple(solve(q, g, d, "0,1")[0]) == (0, 0)
    assert tuple(solve(q, g, d, "0,1", tie_break="last")[0]) == (1, 1)


def test_batched_jit_vmap_and_x64(x64):
    qs, gs, ds = random_game(9, (3, 3, 3), 12)
    want = brute_batch(qs, gs, ds, validate_hierarchy("0,2|1", 3))
    f = lambda q, g, d: stackelberg_equilibrium(list(q), list(g), list(d), hierarchy="0,2|1")
    got = jax.jit(jax.vmap(f, in_axes=(1, 1, 1)))(qs.astype(np.float64), gs.astype(np.float64), ds)
    np.testing.assert_array_equal(np.asarray(got), want)
    assert got.dtype == np.int32 and agent_order(((0, 2), (1,))) == (0, 2, 1)


@pytest.mark.parametrize("hierarchy, kw, message", [
    ("0|1", {}, r"misses agent\(s\) \[2\]"),
    ("0|1|1|2", {}, r"repeats agent\(s\) \[1\]"),
    ("0,1|2", {"leader_rule": "authors"}, "authors' is defined for a chain"),
])
def test_bad_hierarchy(hierarchy, kw, message):
    qs, gs, ds = random_game(0, (2, 2, 2), 1)
    with pytest.raises(ValueError, match=message):
        solve(qs, gs, ds, hierarchy, **kw)
