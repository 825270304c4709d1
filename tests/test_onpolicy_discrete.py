"""MAPPO-L / MACPO on discrete actions with K agents: the categorical policy against closed forms, the sequential
factor for K = 3 against a hand computation, absent agents (merge-cavs) contributing nothing, the multipliers,
the flat-hierarchy rule of the command line, short training runs on highway and merge-cavs (slow) and on the
authors' merge and roundabout."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl.algos.macpo import MACPO
from jaxsmarl.algos.mappo_l import MAPPOL
from jaxsmarl.algos.ppo_base import PPOConfig
from jaxsmarl.categorical import categorical_entropy, categorical_kl, categorical_log_prob
from jaxsmarl.policy_head import CategoricalHead, GaussianHead, policy_head
from train.config import load_config
from train.onpolicy import Transition

K, D, A = 3, 6, 5  # agents, observation width, actions


def _np_log_softmax(x):
    x = np.asarray(x, np.float64)
    z = x - x.max(-1, keepdims=True)
    return z - np.log(np.exp(z).sum(-1, keepdims=True))


def test_categorical_log_prob_entropy_kl_closed_forms(x64):
    rng = np.random.default_rng(0)
    logits, logits_new = rng.normal(size=(2, 7, A)) * 2.0
    action = rng.integers(0, A, size=7)
    lp, lp_new = _np_log_softmax(logits), _np_log_softmax(logits_new)
    np.testing.assert_allclose(categorical_log_prob(jnp.asarray(action), jnp.asarray(logits)),
                               lp[np.arange(7), action], rtol=1e-12)
    np.testing.assert_allclose(categorical_entropy(jnp.asarray(logits)), -(np.exp(lp) * lp).sum(-1), rtol=1e-12)
    np.testing.assert_allclose(categorical_kl(jnp.asarray(logits), jnp.asarray(logits_new)),
                               (np.exp(lp) * (lp - lp_new)).sum(-1), rtol=1e-12)
    np.testing.assert_allclose(categorical_kl(jnp.asarray(logits), jnp.asarray(logits)), 0.0, atol=1e-14)
    # the KL's Hessian in the new logits at the old ones is the Fisher matrix diag(p) - p p^T (MACPO's metric)
    hess = jax.hessian(lambda z: categorical_kl(jnp.asarray(logits[0]), z))(jnp.asarray(logits[0]))
    p = np.exp(lp[0])
    np.testing.assert_allclose(hess, np.diag(p) - np.outer(p, p), atol=1e-12)


def test_policy_head_follows_the_action_space():
    assert isinstance(policy_head(1, 5, 1.0, 0.5), CategoricalHead)
    assert isinstance(policy_head(2, 0, 1.0, 0.5), GaussianHead)
    with pytest.raises(ValueError, match="num_actions >= 1 .* or action_dim >= 1"):
        policy_head(0, 0, 1.0, 0.5)
    head = CategoricalHead(A)
    logits = jnp.asarray([[0.1, 2.0, -1.0, 0.0, 0.5]])
    assert int(head.greedy(logits)[0]) == 1 and head.init(jnp.float32) == {}


def _agent(cls=MAPPOL, **kw):
    cfg = dict(n_agents=K, obs_dim=D, num_actions=A, num_minibatches=2, ppo_epochs=1, hidden=8, cost_limit=1.0,
               gamma=0.5, lambda_lr=0.05)
    cfg.update(kw)
    return cls(PPOConfig(**cfg))


def _rollout(key, T=8, E=4, ep_cost=3.0, present=None):
    k = jax.random.split(key, 5)
    ended = jnp.zeros((T, E), bool).at[-1].set(True)
    present = jnp.ones((T, E, K), bool) if present is None else present
    return Transition(obs=jax.random.normal(k[0], (T, E, K, D)),
                      action=jax.random.randint(k[1], (T, E, K), 0, A), logp=jnp.full((T, E, K), -np.log(A)),
                      reward=jax.random.normal(k[2], (T, E, K)), cost=jax.random.uniform(k[3], (T, E, K)),
                      next_obs=jax.random.normal(k[4], (T, E, K, D)), terminated=~present,
                      done=ended, active=present, ep_returned=ended, ep_cost=jnp.full((T, E, K), ep_cost),
                      present=present)


def test_act_samples_valid_actions_with_their_log_probs():
    agent = _agent()
    st = agent.init(jax.random.PRNGKey(0))
    obs = jax.random.normal(jax.random.PRNGKey(1), (4, K, D))
    action, logp = agent.act(st, obs, jax.random.PRNGKey(2))
    assert action.shape == (4, K) and jnp.issubdtype(action.dtype, jnp.integer)
    assert ((action >= 0) & (action < A)).all()
    obs_n = agent.normalize_obs(st, obs)
    for i in range(K):
        logits = agent.actor_net.apply(jax.tree.map(lambda x: x[i], st.actor)["net"], obs_n[:, i])
        np.testing.assert_allclose(logp[:, i], _np_log_softmax(logits)[np.arange(4), action[:, i]], rtol=1e-5)
    assert agent.greedy_act(st, obs[0]).shape == (K,)
    np.testing.assert_array_equal(agent.env_action(action), action)


class _FactorProbe(MAPPOL):
    """MAPPO-L whose update info also holds the factor each agent's surrogate was weighted by."""

    def agent_update(self, state, i, batch, factor, key):
        state, info = super().agent_update(state, i, batch, factor, key)
        info["factor"] = factor
        return state, info


def test_sequential_factor_is_the_product_over_all_previous_agents_k3():
    """K = 3, sequential: the agent updated third is weighted by the product of the first two agents' new/old
    ratios, the second by the first's, the first by 1; inactive samples contribute ratio 1. The ratios are
    computed here from the updated actors (log-softmax in float64)."""
    agent = _FactorProbe(PPOConfig(n_agents=K, obs_dim=D, num_actions=A, num_minibatches=2, ppo_epochs=2, hidden=8,
                                   actor_lr=3e-2))
    st0 = agent.init(jax.random.PRNGKey(0))
    T, E = 8, 4
    traj = _rollout(jax.random.PRNGKey(1), T, E)
    active = traj.active.at[2:5, 1, 0].set(False)  # agent 0 inactive on some steps
    traj = traj.replace(active=active)
    st, info = jax.jit(agent.update)(st0, traj, jax.random.PRNGKey(3))
    order = [int(i) for i in info["order"]]
    obs_n = agent.normalize_obs(st0, traj.obs).reshape(T * E, K, D)
    act, lo = traj.action.reshape(T * E, K), traj.logp.reshape(T * E, K)
    ratios = []
    for i in range(K):
        logits = agent.actor_net.apply(jax.tree.map(lambda x: x[i], st.actor)["net"], obs_n[:, i])
        lp = _np_log_softmax(logits)[np.arange(T * E), act[:, i]]
        ratios.append(np.where(active.reshape(T * E, K)[:, i], np.exp(lp - np.asarray(lo[:, i], np.float64)), 1.0))
    factor = np.asarray(info["factor"])  # [K, B], agent order
    np.testing.assert_allclose(factor[order[0]], 1.0)
    np.testing.assert_allclose(factor[order[1]], ratios[order[0]], rtol=2e-5)
    np.testing.assert_allclose(factor[order[2]], ratios[order[0]] * ratios[order[1]], rtol=2e-5)
    # both earlier agents moved, so a factor of one ratio only would fail the last check
    assert min(np.abs(ratios[order[0]] - 1).max(), np.abs(ratios[order[1]] - 1).max()) > 1e-3
    assert (ratios[0].reshape(T, E)[2:5, 1] == 1.0).all()


@pytest.mark.parametrize("cls", [MAPPOL, pytest.param(MACPO, marks=pytest.mark.slow)])  # one in the default suite
@pytest.mark.parametrize("per_agent_cost", [False, pytest.param(True, marks=pytest.mark.slow)])  # one default
def test_absent_agent_contributes_nothing(cls, per_agent_cost):
    """Agent 2 is absent in envs 0 and 1 (merge-cavs' inactive slots): replacing everything it recorded there
    (observations, actions, log-probs, rewards, costs, terminations, episode costs) by garbage leaves the whole
    update unchanged, while the same garbage on a present agent changes it."""
    T, E = 8, 4
    present = jnp.ones((T, E, K), bool).at[:, :2, 2].set(False)
    agent = _agent(cls, absent_agents=True, per_agent_cost=per_agent_cost)
    st0 = agent.init(jax.random.PRNGKey(0))
    zeros = lambda x: jnp.where(present if x.ndim == 3 else present[..., None], x, 0)
    traj = _rollout(jax.random.PRNGKey(1), T, E, present=present)
    traj = traj.replace(obs=zeros(traj.obs), next_obs=zeros(traj.next_obs), reward=zeros(traj.reward),
                        cost=zeros(traj.cost), ep_cost=jnp.where(present, traj.ep_cost, 0.0))
    g = jax.random.split(jax.random.PRNGKey(9), 6)

    def garble(tr, where):
        w3 = where[..., None]
        return tr.replace(
            obs=jnp.where(w3, 50 * jax.random.normal(g[0], tr.obs.shape), tr.obs),
            next_obs=jnp.where(w3, 50 * jax.random.normal(g[1], tr.obs.shape), tr.next_obs),
            action=jnp.where(where, jax.random.randint(g[2], tr.action.shape, 0, A), tr.action),
            logp=jnp.where(where, jax.random.uniform(g[3], tr.logp.shape, minval=-4.0, maxval=0.0), tr.logp),
            reward=jnp.where(where, 30 * jax.random.normal(g[4], tr.reward.shape), tr.reward),
            cost=jnp.where(where, 30.0, tr.cost), ep_cost=jnp.where(where, 77.0, tr.ep_cost),
            terminated=jnp.where(where, jax.random.bernoulli(g[5], 0.5, tr.terminated.shape), tr.terminated))

    update = jax.jit(agent.update)
    ref = update(st0, traj, jax.random.PRNGKey(2))
    out = update(st0, garble(traj, ~present), jax.random.PRNGKey(2))
    for a, b in zip(jax.tree.leaves(ref), jax.tree.leaves(out)):
        np.testing.assert_array_equal(a, b)
    other = jnp.zeros_like(present).at[:, :2, 1].set(True)  # the same garbage on a present agent
    moved = update(st0, garble(traj, other), jax.random.PRNGKey(2))
    assert any(not np.array_equal(a, b) for a, b in zip(jax.tree.leaves(ref[0].actor), jax.tree.leaves(moved[0].actor)))
    # J_c counts agent 2 only in the episodes it drove (envs 2, 3); the agent mean over the agents present
    expect = [3.0, 3.0, 3.0] if per_agent_cost else [3.0] * K
    np.testing.assert_allclose(ref[0].episode_cost, expect)
    costs = jnp.where(present, jnp.asarray([1.0, 2.0, 6.0]), 0.0)
    st = update(st0, traj.replace(ep_cost=costs), jax.random.PRNGKey(2))[0]
    # agent mean per episode: envs 0-1 (1 + 2) / 2 = 1.5, envs 2-3 (1 + 2 + 6) / 3 = 3; mean over 4 episodes 2.25
    np.testing.assert_allclose(st.episode_cost, [1.0, 2.0, 6.0] if per_agent_cost else [2.25] * K, rtol=1e-6)


@pytest.mark.parametrize("cls", [MAPPOL, pytest.param(MACPO, marks=pytest.mark.slow)])  # one in the default suite
def test_k3_discrete_update_is_finite_and_multipliers_follow_the_cost(cls):
    """Three agents with categorical policies: updates stay finite; MAPPO-L's multipliers rise while the episode
    cost exceeds the limit and fall below it; MACPO's trust region holds."""
    for ep_cost, rises in ((5.0, True), (0.0, False)):
        agent = _agent(cls)
        st = agent.init(jax.random.PRNGKey(0))
        lam = [np.asarray(st.lagrange)]
        update = jax.jit(agent.update)
        for i in range(3):
            st, info = update(st, _rollout(jax.random.PRNGKey(i), ep_cost=ep_cost), jax.random.PRNGKey(i))
            lam.append(np.asarray(st.lagrange))
        assert all(np.isfinite(x).all() for x in jax.tree.leaves(st))
        if cls is MAPPOL:
            steps = np.diff(np.stack(lam), axis=0)
            assert (steps > 0).all() if rises else (steps < 0).all(), lam
        else:
            assert (np.asarray(info["kl"]) < agent.config.kl_threshold).all()


def test_hierarchy_is_refused_unless_flat():
    for algo in ("mappo-l", "macpo"):
        with pytest.raises(ValueError, match=r"no-hierarchy baseline .* '0\|1\|2' has 3 levels.*flat '0,1,2'"):
            load_config("highway", algo, {"agents": 3, "hierarchy": "0|1|2"})
        with pytest.raises(ValueError, match=r"misses agent\(s\) \[2\]"):
            load_config("highway", algo, {"agents": 3, "hierarchy": "0,1"})
        for flat in ("0,1,2", "2,0,1", "flat"):
            cfg = load_config("highway", algo, {"agents": 3, "hierarchy": flat})
            assert "hierarchy" not in cfg and cfg["agents"] == 3
    assert load_config("merge-cavs", "mappo-l", {"agents": 4})["agents"] == 4


def _short_run(scenario, algo, agents, **kw):
    from train.build import make_train
    from train.trainer import seed_keys

    over = dict(agents=agents, num_seeds=1, num_envs=4, rollout_length=8, total_steps=96, chunk_steps=96,
                checkpoint_every=0, eval_episodes=1, eval_max_steps=5, num_minibatches=2, hidden=16,
                cost_limit=0.0)
    over.update(kw)
    cfg = load_config(scenario, algo, over)
    trainer = make_train(cfg)
    state, m = jax.jit(trainer.train)(seed_keys(cfg)[0])
    rec = jax.jit(trainer.evaluate)(state.agent, jax.random.PRNGKey(0))
    return state, m, rec


@pytest.mark.slow
@pytest.mark.parametrize("scenario, algo, agents", [("highway", "mappo-l", 3), ("highway", "macpo", 3),
                                                    ("merge-cavs", "mappo-l", 4)])
def test_short_k_agent_training_run(scenario, algo, agents):
    """Through the on-policy loop on a discrete K-agent scenario: finite, every agent's multiplier moves (MAPPO-L,
    limit 0 below any cost), greedy evaluation runs."""
    state, m, rec = _short_run(scenario, algo, agents, **({"ppo_epochs": 1} if algo == "mappo-l" else {}))
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(state.agent))
    lam = np.asarray(m["update"]["lagrange"]) if algo == "mappo-l" else None
    if lam is not None:
        assert lam.shape == (3, agents) and (lam[-1] != lam[0]).all()
    assert rec["length"].shape == (1,)


@pytest.mark.parametrize("scenario, algo, agents", [("merge", "mappo-l", 3),
                                                    pytest.param("roundabout", "macpo", 2, marks=pytest.mark.slow),
                                                    pytest.param("merge", "macpo", 2, marks=pytest.mark.slow)])
def test_authors_scenarios_train_on_policy(scenario, algo, agents):
    """The authors' merge and roundabout (two agents, or K on the traffic core) through the on-policy loop: their
    configurations load, the updates stay finite, every agent gets a multiplier and greedy evaluation runs."""
    cfg = load_config(scenario, algo, {"agents": agents})
    assert cfg["scenario"] == scenario and cfg["num_envs"] * cfg["rollout_length"] > 0
    kw = {"ppo_epochs": 1} if algo == "mappo-l" else {}
    state, m, rec = _short_run(scenario, algo, agents, eval_max_steps=200, **kw)  # the time limit ends it first
    assert all(np.isfinite(np.asarray(x)).all() for x in jax.tree.leaves(state.agent))
    if algo == "mappo-l":
        lam = np.asarray(m["update"]["lagrange"])
        assert lam.shape == (3, agents) and np.isfinite(lam).all()
    assert np.asarray(rec["returned"]).all() and (np.asarray(rec["length"]) >= 1).all()
