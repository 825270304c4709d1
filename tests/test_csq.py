"""CSQ (Algorithm 1): critics, acting, TD targets (p14 at s'), per-agent bootstrap gating, soft update."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl import networks
from jaxsmarl.algos.csq import CSQAgent, CSQConfig, CSQState, Transition

A = 5
GAMMA = 0.95


def _agent(**kw) -> CSQAgent:
    return CSQAgent(CSQConfig(**kw))


def _ref_values(agent: CSQAgent, params, obs) -> np.ndarray:
    """[B, 2, 2, A, A] by applying each flax critic to concat(o_i, onehot(a1), onehot(a2)), pair by pair."""
    b = obs.shape[0]
    apply = jax.jit(agent.module.apply)
    out = np.zeros((b, 2, 2, A, A))
    for i in range(2):
        for k in range(2):
            p = jax.tree.map(lambda x: x[i, k], params)
            for a1 in range(A):
                for a2 in range(A):
                    oh = np.broadcast_to(np.eye(2 * A, dtype=np.float32)[[a1, A + a2]].sum(0), (b, 2 * A))
                    out[:, i, k, a1, a2] = np.asarray(apply(p, obs[:, i], oh))
    return out


def _constrained_argmax(q, g, d):
    """Paper rule + documented fallback: max q over g <= d (first index on ties); if none, min g then max q."""
    feas = [a for a in range(len(q)) if g[a] <= d]
    if feas:
        return max(feas, key=lambda a: (q[a], -a))
    lo = min(g)
    return max([a for a in range(len(q)) if g[a] == lo], key=lambda a: (q[a], -a))


def _brute_p14(v, d):
    """Constrained Stackelberg equilibrium (p14) of one state, v: [2 agents, 2 kinds, A, A]."""
    q1, g1, q2, g2 = v[0, 0], v[0, 1], v[1, 0], v[1, 1]
    br = [_constrained_argmax(q2[a1], g2[a1], d[1]) for a1 in range(A)]
    a1 = _constrained_argmax([q1[a, br[a]] for a in range(A)], [g1[a, br[a]] for a in range(A)], d[0])
    return a1, br[a1]


def _brute_authors(v, d):
    """The authors' leader rule: best pair under the leader's own Q1 s.t. G1 <= d1 (last pair on ties),
    fallback to the unconstrained best pair; follower: constrained best response to a1 (fallback argmax)."""
    q1, g1, q2, g2 = v[0, 0], v[0, 1], v[1, 0], v[1, 1]
    best, best_pair = -np.inf, None
    for a1 in range(A):
        for a2 in range(A):
            if g1[a1, a2] <= d[0] and q1[a1, a2] >= best:
                best, best_pair = q1[a1, a2], (a1, a2)
    if best_pair is None:
        best_pair = max(((a1, a2) for a1 in range(A) for a2 in range(A)), key=lambda p: q1[p])
    a1 = best_pair[0]
    feas = [a for a in range(A) if g2[a1, a] <= d[1]]
    a2 = max(feas, key=lambda a: (q2[a1, a], a)) if feas else int(np.argmax(q2[a1]))
    return a1, a2


def _batch(key, b=32, terminated=None, truncated=None):
    k = jax.random.split(key, 5)
    return Transition(
        obs=3.0 * jax.random.normal(k[0], (b, 2, 8)), action=jax.random.randint(k[1], (b, 2), 0, A),
        reward=jax.random.normal(k[2], (b, 2)), cost=jnp.abs(jax.random.normal(k[3], (b, 2))),
        next_obs=3.0 * jax.random.normal(k[4], (b, 2, 8)),
        terminated=jnp.zeros((b, 2), bool) if terminated is None else terminated,
        truncated=jnp.zeros((b,), bool) if truncated is None else truncated)


@pytest.fixture(scope="module")
def setup():
    """Online and (different) target critics; threshold 0 makes about half of the pairs infeasible."""
    agent = _agent(cost_threshold=(0.0, 0.0))
    st = jax.jit(agent.init)(jax.random.PRNGKey(0))
    target = jax.jit(agent.init)(jax.random.PRNGKey(1)).params
    st = st.replace(target_params=target)
    return agent, st


def test_batched_critics_equal_the_flax_module(setup):
    agent, st = setup
    obs = 3.0 * jax.random.normal(jax.random.PRNGKey(2), (6, 2, 8))
    np.testing.assert_allclose(jax.jit(agent.values)(st.params, obs), _ref_values(agent, st.params, obs), rtol=1e-5,
                               atol=1e-5)
    a = jax.random.randint(jax.random.PRNGKey(3), (6, 2), 0, A)
    at = networks.values_at(st.params, obs, a, (A, A))
    ref = _ref_values(agent, st.params, obs)[np.arange(6), :, :, np.asarray(a[:, 0]), np.asarray(a[:, 1])]
    np.testing.assert_allclose(at, ref, rtol=1e-5, atol=1e-5)


def test_init_targets_equal_online_and_critics_independent():
    agent = _agent()
    st = jax.jit(agent.init)(jax.random.PRNGKey(0))
    for x, y in zip(jax.tree.leaves(st.params), jax.tree.leaves(st.target_params)):
        np.testing.assert_array_equal(x, y)
    k = st.params["params"]["_Dense_1"]["kernel"]  # [2 agents, 2 kinds, 64, 64]
    assert k.shape == (2, 2, 64, 64)
    assert not np.allclose(k[0, 0], k[0, 1]) and not np.allclose(k[0, 0], k[1, 0])
    assert st.params["params"]["_Dense_0"]["kernel"].shape == (2, 2, 8 + 2 * A, 64)  # obs + one-hot joint action


def test_td_targets_match_hand_computation(setup):
    """y_i = r_i + gamma (1 - t_i) Q_i^targ(s', a'), a' = p14 of the ONLINE critics at s' (brute force)."""
    agent, st = setup
    batch = _batch(jax.random.PRNGKey(4))
    y = np.asarray(jax.jit(agent.td_targets)(st, batch, jax.random.PRNGKey(0), jnp.zeros(2)))
    v_online = _ref_values(agent, st.params, batch.next_obs)
    v_target = _ref_values(agent, st.target_params, batch.next_obs)
    n_infeasible_rows = 0
    for b in range(batch.obs.shape[0]):
        a1, a2 = _brute_p14(v_online[b], (0.0, 0.0))
        n_infeasible_rows += int(np.all(v_online[b, 1, 1] > 0))
        for i in range(2):
            exp_q = float(batch.reward[b, i]) + GAMMA * v_target[b, i, 0, a1, a2]
            exp_g = float(batch.cost[b, i]) + GAMMA * v_target[b, i, 1, a1, a2]
            np.testing.assert_allclose(y[b, i], [exp_q, exp_g], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("d, infeasible",
                         [((0.0, 0.0), "min_cost"), ((-0.05, 0.05), "argmax"), ((5.0, 5.0), "min_cost")])
def test_follower_first_target_equilibrium_equals_full_grid(d, infeasible):
    """solve_equilibrium (follower grid + leader at (a1, BR(a1)) only) == p14 on the full joint-value grid."""
    agent = _agent(cost_threshold=d, infeasible=infeasible)
    st = jax.jit(agent.init)(jax.random.PRNGKey(3))
    obs = 3.0 * jax.random.normal(jax.random.PRNGKey(4), (3000, 2, 8))
    fast = jax.jit(agent.solve_equilibrium)(st.params, obs)
    full = jax.jit(lambda p, o: agent.equilibrium(agent.values(p, o)))(st.params, obs)
    np.testing.assert_array_equal(fast, full)


def test_td_target_constant_critics_by_hand():
    """Critics with zero last-layer weights output their bias: Q1targ = 2, G1targ = 1, Q2targ = -1, G2targ = 3."""
    agent = _agent()
    st = jax.jit(agent.init)(jax.random.PRNGKey(0))
    bias = jnp.array([[2.0, 1.0], [-1.0, 3.0]])[:, :, None]

    def const(p):
        p = jax.tree.map(lambda x: x, p)
        last = p["params"]["_Dense_3"]
        p["params"]["_Dense_3"] = {"kernel": jnp.zeros_like(last["kernel"]), "bias": bias}
        return p

    st = st.replace(target_params=const(st.target_params))
    batch = Transition(obs=jnp.zeros((1, 2, 8)), action=jnp.zeros((1, 2), jnp.int32), reward=jnp.array([[1.0, 0.5]]),
                       cost=jnp.array([[0.0, 5.0]]), next_obs=jnp.ones((1, 2, 8)),
                       terminated=jnp.array([[False, True]]), truncated=jnp.array([False]))
    y = np.asarray(jax.jit(agent.td_targets)(st, batch, jax.random.PRNGKey(0), jnp.zeros(2)))[0]
    # leader: 1 + 0.95 * 2 = 2.9 and 0 + 0.95 * 1 = 0.95; follower terminated: its own r and c only.
    np.testing.assert_allclose(y, [[2.9, 0.95], [0.5, 5.0]], rtol=1e-6)


def test_per_agent_bootstrap_gating(setup):
    agent, st = setup
    term = jnp.array([[True, False], [False, True], [False, False], [True, True]])
    batch = _batch(jax.random.PRNGKey(5), b=4, terminated=term, truncated=jnp.array([False, False, True, True]))
    rc = np.stack([batch.reward, batch.cost], -1)
    y = np.asarray(jax.jit(agent.td_targets)(st, batch, jax.random.PRNGKey(0), jnp.zeros(2)))
    term = np.asarray(term)
    # a done agent's target is exactly its own (r, c); the other agent keeps bootstrapping
    np.testing.assert_array_equal(y[term], rc[term])
    assert np.all(np.abs(y[~term] - rc[~term]) > 1e-6)  # truncation (rows 2, 3) does not stop bootstrapping
    # authors' option: the time limit also ends bootstrapping
    authors = CSQAgent(dataclasses.replace(agent.config, bootstrap_on_truncation=False))
    y2 = np.asarray(jax.jit(authors.td_targets)(st, batch, jax.random.PRNGKey(0), jnp.zeros(2)))
    np.testing.assert_array_equal(y2[2], rc[2])
    np.testing.assert_array_equal(y2[:2], y[:2])


def test_td_action_state_current_uses_s_not_s_prime(setup):
    agent, st = setup
    batch = _batch(jax.random.PRNGKey(6), b=16)
    cur = CSQAgent(dataclasses.replace(agent.config, td_action_state="current"))
    y = np.asarray(jax.jit(cur.td_targets)(st, batch, jax.random.PRNGKey(0), jnp.zeros(2)))
    v_online_s = _ref_values(agent, st.params, batch.obs)
    v_target = _ref_values(agent, st.target_params, batch.next_obs)
    for b in range(16):
        a1, a2 = _brute_p14(v_online_s[b], (0.0, 0.0))
        np.testing.assert_allclose(y[b, :, 0], np.asarray(batch.reward[b]) + GAMMA * v_target[b, :, 0, a1, a2],
                                   rtol=1e-5, atol=1e-5)


def test_greedy_and_epsilon_acting(setup):
    agent, st = setup
    obs = 3.0 * jax.random.normal(jax.random.PRNGKey(7), (64, 2, 8))
    v = _ref_values(agent, st.params, obs)
    greedy = np.asarray(jax.jit(agent.act)(st, obs, jax.random.PRNGKey(0), jnp.zeros(2)))
    np.testing.assert_array_equal(greedy, np.asarray(jax.jit(agent.greedy_act)(st, obs)))
    for b in range(64):
        assert tuple(greedy[b]) == _brute_p14(v[b], (0.0, 0.0))
    # leader always random, follower greedy: the follower best-responds to the EXECUTED leader action
    acts = np.asarray(jax.jit(agent.act)(st, obs, jax.random.PRNGKey(1), jnp.array([1.0, 0.0])))
    for b in range(64):
        a1 = acts[b, 0]
        assert acts[b, 1] == _constrained_argmax(v[b, 1, 0, a1], v[b, 1, 1, a1], 0.0)
    assert len(set(acts[:, 0])) == A
    # follower always random: uniform over its actions, leader unchanged
    many = jnp.repeat(obs[:1], 2000, 0)
    acts = np.asarray(jax.jit(agent.act)(st, many, jax.random.PRNGKey(2), jnp.array([0.0, 1.0])))
    assert np.all(acts[:, 0] == greedy[0, 0])
    assert np.bincount(acts[:, 1], minlength=A).min() > 300


def test_authors_leader_rule(setup):
    agent, st = setup
    authors = CSQAgent(dataclasses.replace(agent.config, leader_rule="authors", infeasible="argmax"))
    obs = 3.0 * jax.random.normal(jax.random.PRNGKey(8), (64, 2, 8))
    v = _ref_values(agent, st.params, obs)
    acts = np.asarray(jax.jit(authors.greedy_act)(st, obs))
    for b in range(64):
        assert tuple(acts[b]) == _brute_authors(v[b], (0.0, 0.0))


def test_epsilon_schedule_authors_default():
    agent = _agent()  # 0.1 -> 0 at 5e-6 per step (merge CSQ)
    np.testing.assert_allclose(agent.epsilon(0), [0.1, 0.1])
    np.testing.assert_allclose(agent.epsilon(10000), [0.05, 0.05], atol=1e-7)
    np.testing.assert_allclose(agent.epsilon(20000), [0.0, 0.0], atol=1e-7)
    floor = _agent(eps_min=(0.05, 0.02))
    np.testing.assert_allclose(floor.epsilon(19000), [0.05, 0.02], atol=1e-7)


def test_soft_update_rule_and_period(setup):
    agent, st = setup
    batch = _batch(jax.random.PRNGKey(9))
    for n, expect_soft in ((0, False), (3, False), (10, True), (20, True)):
        s = st.replace(n_updates=jnp.int32(n))
        new, _ = jax.jit(agent.update)(s, batch, jax.random.PRNGKey(0), jnp.zeros(2))
        assert int(new.n_updates) == n + 1
        for t_old, t_new, p_new in zip(jax.tree.leaves(st.target_params), jax.tree.leaves(new.target_params),
                                       jax.tree.leaves(new.params)):
            expect = 0.99 * np.asarray(t_old) + 0.01 * np.asarray(p_new) if expect_soft else np.asarray(t_old)
            np.testing.assert_allclose(t_new, expect, rtol=1e-6, atol=1e-7)


def test_critics_update_independently(setup):
    """One Adam over the stacked critics == one optimizer per critic: changing agent 1's data leaves agent 0's
    new parameters untouched."""
    agent, st = setup
    batch = _batch(jax.random.PRNGKey(10))
    new_a, info_a = jax.jit(agent.update)(st, batch, jax.random.PRNGKey(0), jnp.zeros(2))
    batch_b = batch.replace(reward=batch.reward.at[:, 1].add(10.0), cost=batch.cost.at[:, 1].add(3.0))
    new_b, info_b = jax.jit(agent.update)(st, batch_b, jax.random.PRNGKey(0), jnp.zeros(2))
    for x, y in zip(jax.tree.leaves(new_a.params), jax.tree.leaves(new_b.params)):
        np.testing.assert_array_equal(x[0], y[0])
    assert float(info_a["loss_q"][1]) != float(info_b["loss_q"][1])
    np.testing.assert_array_equal(info_a["loss_q"][0], info_b["loss_q"][0])


def test_update_fits_terminal_rewards():
    """With every agent terminated the targets are (r, c); repeated updates drive the TD loss down."""
    agent = _agent(lr=3e-3)
    st = jax.jit(agent.init)(jax.random.PRNGKey(0))
    batch = _batch(jax.random.PRNGKey(11), b=16, terminated=jnp.ones((16, 2), bool))
    upd = jax.jit(lambda s: agent.update(s, batch, jax.random.PRNGKey(0), jnp.zeros(2)))
    _, info0 = upd(st)
    for _ in range(300):
        st, info = upd(st)
    assert float(jnp.sum(info["loss_q"] + info["loss_g"])) < 0.05 * float(jnp.sum(info0["loss_q"] + info0["loss_g"]))
    assert isinstance(st, CSQState)


@pytest.mark.slow
def test_merge_csq_learns_to_merge_safely(tmp_path):
    """The authors' merge CSQ budget (20k steps) on 4 seeds: near-zero crashes at the end (authors: 0.2%)."""
    from train.config import load_config
    from train.run import run

    cfg = load_config("merge", "csq", dict(num_seeds=4, checkpoint_every=0, eval_episodes=1))
    res = run(cfg, str(tmp_path / "run"), verbose=False)["summary"]
    assert res["summary"]["crash"]["last"][0] < 0.1
    assert res["summary"]["total_return"]["last"][0] > 50.0
    assert res["eval"]["crash"]["mean_ci"][0] <= 0.25
