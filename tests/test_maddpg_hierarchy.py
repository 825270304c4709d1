"""The MADDPG family for K agents and any hierarchy (the paper's multi-agent expansion, docs/algorithms.md): actor
gradients through every lower level against finite differences of explicitly written hierarchical decisions
(a three-level chain in two agent orders, two leaders over two followers), the flat hierarchy against MADDPG's
independent update, the sequential actor order agent after agent, configuration errors, and a short K = 3 training run
on racetrack-v0."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from jaxsmarl.algos.maddpg import MADDPGAgent, MADDPGConfig, Transition
from train.config import load_config

D = 6
LAM = jnp.array([0.7, 1.3, 0.4, 0.9])


def _agent(k, **kw) -> MADDPGAgent:
    base = dict(hidden_sizes=(5,), lambda_rule="dual", n_agents=k, cost_threshold=(0.05, -0.1, 0.2, 0.0)[:k],
                noise_start=(0.1,) * k, noise_min=(0.0,) * k, eps_start=(0.1,) * k, eps_min=(0.0,) * k, obs_dim=D)
    base.update(kw)
    return MADDPGAgent(MADDPGConfig(**base))


def _setup(k, **kw):
    agent = _agent(k, **kw)
    st = jax.tree.map(lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x,
                      agent.init(jax.random.PRNGKey(3)))
    obs = jax.random.normal(jax.random.PRNGKey(4), (6, k, D))
    return agent, st, obs


def _mu(agent, theta, obs_i, *above):
    return agent.actor.apply(theta, jnp.concatenate((obs_i,) + above, -1))


# The hierarchical decisions written out by hand: agent actions from every agent's parameters.
def _chain_012(agent, th, obs):
    a0 = _mu(agent, th[0], obs[:, 0])
    a1 = _mu(agent, th[1], obs[:, 1], a0)
    a2 = _mu(agent, th[2], obs[:, 2], a0, a1)
    return [a0, a1, a2]


def _chain_201(agent, th, obs):  # agent 2 leads, then agent 0, then agent 1
    a2 = _mu(agent, th[2], obs[:, 2])
    a0 = _mu(agent, th[0], obs[:, 0], a2)
    a1 = _mu(agent, th[1], obs[:, 1], a2, a0)
    return [a0, a1, a2]


def _two_over_two(agent, th, obs):  # leaders 0 and 1 side by side, followers 2 and 3 reading both
    a0 = _mu(agent, th[0], obs[:, 0])
    a1 = _mu(agent, th[1], obs[:, 1])
    return [a0, a1, _mu(agent, th[2], obs[:, 2], a0, a1), _mu(agent, th[3], obs[:, 3], a0, a1)]


def _flat(agent, th, obs):
    return [_mu(agent, th[i], obs[:, i]) for i in range(obs.shape[1])]


DECISIONS = {"0|1|2": (3, _chain_012), "2|0|1": (3, _chain_201), "0,1|2,3": (4, _two_over_two)}


def _objective(agent, st, obs, decide, i, frozen=None):
    """Agent i's actor loss as a function of theta_i alone, every other actor responding (or, with ``frozen``,
    the other agents' actions held at those values)."""
    c = agent.config

    def f(theta):
        th = list(st.actors)
        th[i] = theta
        acts = decide(agent, th, obs)
        if frozen is not None:
            acts = [acts[j] if j == i else frozen[j] for j in range(len(acts))]
        s = obs.reshape(obs.shape[0], -1)
        a = jnp.concatenate(acts, -1)
        q = agent.critic.apply(jax.tree.map(lambda x: x[i, 0], st.critics), s, a)
        g = agent.critic.apply(jax.tree.map(lambda x: x[i, 1], st.critics), s, a)
        return jnp.mean(-q + LAM[i] * (g - c.cost_threshold[i]))

    return f


def _fd_grad(f, params, h=1e-6):
    flat, unravel = ravel_pytree(params)
    eye = jnp.eye(flat.size, dtype=flat.dtype) * h
    return np.asarray(jax.jit(jax.vmap(lambda e: (f(unravel(flat + e)) - f(unravel(flat - e))) / (2 * h)))(eye))


def _grads(agent, st, obs, through=None):
    lam = LAM[: agent.n]
    return jax.grad(lambda a: jnp.sum(agent.actor_losses(a, st.critics, lam, obs, through)[0]))(st.actors)


@pytest.mark.parametrize("hierarchy", list(DECISIONS))
def test_every_actor_gradient_goes_through_the_levels_below(hierarchy, x64):
    k, decide = DECISIONS[hierarchy]
    agent, st, obs = _setup(k, hierarchy=hierarchy)
    np.testing.assert_allclose(agent.greedy_act(st, obs), jnp.stack(decide(agent, st.actors, obs), 1), rtol=1e-12)
    grads, naive = _grads(agent, st, obs), _grads(agent, st, obs, through=False)
    acts = decide(agent, st.actors, obs)
    for i in range(k):
        fd = _fd_grad(_objective(agent, st, obs, decide, i), st.actors[i])
        np.testing.assert_allclose(ravel_pytree(grads[i])[0], fd, rtol=1e-5, atol=1e-8, err_msg=f"agent {i}")
        if i in agent.levels[-1]:  # nothing below the last level: the naive gradient is the same
            np.testing.assert_array_equal(ravel_pytree(naive[i])[0], ravel_pytree(grads[i])[0])
            continue
        # the naive gradient holds every other action fixed: the response terms of the levels below are missing
        fd_frozen = _fd_grad(_objective(agent, st, obs, decide, i, frozen=acts), st.actors[i])
        np.testing.assert_allclose(ravel_pytree(naive[i])[0], fd_frozen, rtol=1e-5, atol=1e-8)
        # the naive gradient differs by far more than the finite-difference tolerance (rtol 1e-5) above
        assert np.linalg.norm(fd_frozen - fd) > 0.01 * np.linalg.norm(fd), i


def _random_batch(obs, seed):
    """A replay batch of three agents around ``obs [B, 3, D]`` with random actions, rewards, costs and next states."""
    k = jax.random.split(jax.random.PRNGKey(seed), 4)
    b = obs.shape[0]
    return Transition(obs=obs, action=jax.random.uniform(k[0], (b, 3, 1), jnp.float64, -1, 1),
                      reward=jax.random.normal(k[1], (b, 3)), cost=jax.random.uniform(k[2], (b, 3)),
                      next_obs=jax.random.normal(k[3], (b, 3, D)), terminated=jnp.zeros((b, 3), bool),
                      truncated=jnp.zeros((b,), bool))


def test_flat_hierarchy_is_maddpgs_independent_update(x64):
    """``stackelberg`` with the one-level hierarchy '0,1,2' is MADDPG: the same update, bit for bit, and each
    actor's gradient is that of its own critic with the other agents' actions held fixed."""
    flat, st, obs = _setup(3, hierarchy="0,1,2")
    plain = _agent(3, stackelberg=False)
    assert plain.levels == flat.levels == ((0, 1, 2),)
    batch = _random_batch(obs, 7)
    out_flat = flat.update(st, batch, jax.random.PRNGKey(0))
    out_plain = plain.update(st, batch, jax.random.PRNGKey(0))
    for x, y in zip(jax.tree.leaves(out_flat), jax.tree.leaves(out_plain)):
        np.testing.assert_array_equal(x, y)
    grads = _grads(flat, st, obs)
    acts = _flat(flat, st.actors, obs)
    for i in range(3):
        fd = _fd_grad(_objective(flat, st, obs, _flat, i, frozen=acts), st.actors[i])
        np.testing.assert_allclose(ravel_pytree(grads[i])[0], fd, rtol=1e-5, atol=1e-8)


def test_two_agent_chain_is_the_default_leader_follower(x64):
    agent, st, obs = _setup(2)
    named, _, _ = _setup(2, hierarchy="0|1")
    assert agent.levels == named.levels == ((0,), (1,))
    for x, y in zip(jax.tree.leaves(_grads(agent, st, obs)), jax.tree.leaves(_grads(named, st, obs))):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("hierarchy,stackelberg", [("0|1|2", True), ("0,1,2", False)])
def test_sequential_actor_order_steps_agent_after_agent(x64, hierarchy, stackelberg):
    """``actor_order='sequential'`` on the chain 0|1|2 and on one level (C-MADDPG's flat agents): agent 1's actor
    loss is taken with agent 0's stepped actor and agent 2's unstepped one; agent 2's with both stepped actors
    before it."""
    agent, st, obs = _setup(3, hierarchy=hierarchy, stackelberg=stackelberg, actor_order="sequential")
    batch = _random_batch(obs, 8)
    new, info = agent.update(st, batch, jax.random.PRNGKey(0))
    lam = st.lam
    loss = lambda actors: agent.actor_losses(actors, st.critics, lam, obs)[0]
    first = loss(st.actors)[0]
    second = loss((new.actors[0], st.actors[1], st.actors[2]))[1]
    third = loss((new.actors[0], new.actors[1], st.actors[2]))[2]
    np.testing.assert_allclose(info["actor_loss"], [first, second, third], rtol=1e-12)
    # and agent 2's step is the Adam step of that loss's gradient (first Adam step: lr * sign of the gradient)
    g2 = jax.grad(lambda t: loss((new.actors[0], new.actors[1], t))[2])(st.actors[2])
    step = ravel_pytree(new.actors[2])[0] - ravel_pytree(st.actors[2])[0]
    g2 = ravel_pytree(g2)[0]
    big = np.abs(g2) > 1e-5  # where Adam's epsilon (1e-8) is negligible
    assert big.sum() >= 5
    np.testing.assert_allclose(step[big], -agent.config.lr_actor * np.sign(g2[big]), rtol=1e-2)


def test_configuration_for_k_agents():
    cfg = load_config("racetrack-v0", "cs-maddpg", {"agents": 4, "hierarchy": "0, 1 | 2,3"})
    assert cfg["hierarchy"] == "0,1|2,3" and cfg["cost_threshold"] == [1.0] * 4 and cfg["noise_start"] == [0.1] * 4
    assert load_config("racetrack-v0", "maddpg")["agents"] == 3
    with pytest.raises(ValueError, match="has no leaders and followers.*use cs-maddpg"):
        load_config("racetrack-v0", "c-maddpg", {"hierarchy": "0|1|2"})
    assert load_config("racetrack-v0", "maddpg", {"hierarchy": "0,1,2"})["hierarchy"] == "0,1,2"
    with pytest.raises(ValueError, match="misses agent"):
        load_config("racetrack-v0", "s-maddpg", {"hierarchy": "0|1"})
    with pytest.raises(ValueError, match="'agents' for scenario 'racetrack-v0' must be 2..8"):
        load_config("racetrack-v0", "s-maddpg", {"agents": 9})
    with pytest.raises(ValueError, match="one value per agent"):
        MADDPGConfig(n_agents=3)
    with pytest.raises(ValueError, match="several levels"):
        _agent(3, stackelberg=False, hierarchy="0|1,2")


def test_three_agent_training_run_on_racetrack_v0_is_finite():
    from train.build import make_train
    from train.trainer import seed_keys

    cfg = load_config("racetrack-v0", "cs-maddpg", dict(
        agents=3, hierarchy="0|1|2", num_seeds=1, num_envs=2, total_steps=48, chunk_steps=48, warmup=16,
        batch_size=8, buffer_size=64, hidden_sizes=[8], eval_episodes=0, checkpoint_every=0))
    trainer = make_train(cfg)
    assert trainer.env.num_agents == 3
    state, metrics = jax.jit(trainer.train)(seed_keys(cfg)[0])
    assert int(state.agent.n_updates) == 48 // 2 - 16 // 2 + 1
    for x in jax.tree.leaves((state.agent, metrics["update"])):
        assert bool(jnp.all(jnp.isfinite(x))), x
    assert metrics["update"]["actor_loss"].shape[-1] == 3 and metrics["update"]["lam"].shape[-1] == 3
    assert float(jnp.max(jnp.abs(state.agent.critics["params"]["_Dense_0"]["kernel"]))) > 0
