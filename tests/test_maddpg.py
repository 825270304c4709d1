"""CS-MADDPG family (Algorithm 2): Stackelberg actor gradients (p23, p25) against finite differences, TD targets,
soft updates, exploration schedule, learning on a toy problem with a closed-form optimum, registry and CLI."""

import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from jaxsmarl.algos.maddpg import (
    MADDPGAgent,
    MADDPGConfig,
    Transition,
    actor_columns,
    critic_values,
    critic_values_columns,
)
from jaxsmarl.layout import ENV_VAR
from train.config import load_config

D = 8


def _agent(**kw) -> MADDPGAgent:
    base = dict(hidden_sizes=(5,), lambda_rule="dual", cost_threshold=(0.05, -0.1))
    base.update(kw)
    return MADDPGAgent(MADDPGConfig(**base))


def _critic_ref(agent, critics, i, k, obs, a1, a2):
    """Agent i's critic of kind k by the flax module on concat(s, a1, a2), s = [o1, o2] or o_i."""
    p = jax.tree.map(lambda x: x[i, k], critics)
    s = obs.reshape(obs.shape[0], -1) if agent.config.critic_input == "joint" else obs[:, i]
    return agent.critic.apply(p, s, jnp.concatenate([a1, a2], -1))


def _leader_objective(agent, lam, obs, critics, theta2):
    """Leader's loss as a function of theta1 alone, the follower's actor responding (p20/p21)."""
    d1 = agent.config.cost_threshold[0]

    def f(theta1):
        a1 = agent.actor.apply(theta1, obs[:, 0])
        a2 = agent.actor.apply(theta2, jnp.concatenate([obs[:, 1], a1], -1))
        q = _critic_ref(agent, critics, 0, 0, obs, a1, a2)
        g = _critic_ref(agent, critics, 0, 1, obs, a1, a2)
        return jnp.mean(-q + lam[0] * (g - d1))

    return f


def _fd_grad(f, params, h=1e-6):
    """Central finite differences of ``f`` at ``params`` (in float64), one coordinate at a time."""
    flat, unravel = ravel_pytree(jax.tree.map(lambda x: x.astype(jnp.float64), params))
    eye = jnp.eye(flat.size, dtype=flat.dtype) * h
    fv = jax.jit(jax.vmap(lambda e: (f(unravel(flat + e)) - f(unravel(flat - e))) / (2 * h)))
    return np.asarray(fv(eye))


@pytest.fixture
def setup(x64):
    agent = _agent()
    st = jax.tree.map(lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x,
                      agent.init(jax.random.PRNGKey(3)))
    obs = jax.random.normal(jax.random.PRNGKey(4), (6, 2, D))
    lam = jnp.array([0.7, 1.3])
    return agent, st, obs, lam


def test_leader_gradient_goes_through_the_follower(setup):
    agent, st, obs, lam = setup
    grad = lambda through: ravel_pytree(jax.grad(
        lambda a: agent.actor_losses(a, st.critics, lam, obs, through)[0][0])(st.actors)[0])[0]
    g_stack, g_direct = np.asarray(grad(True)), np.asarray(grad(None))
    np.testing.assert_array_equal(g_stack, g_direct)  # stackelberg=True is the default path
    fd = _fd_grad(_leader_objective(agent, lam, obs, st.critics, st.actors[1]), st.actors[0])
    np.testing.assert_allclose(g_stack, fd, rtol=1e-5, atol=1e-8)
    g_naive = np.asarray(grad(False))  # ignores d mu2 / d a1
    assert np.linalg.norm(g_naive - fd) > 0.05 * np.linalg.norm(fd)
    # the naive gradient is the finite difference with the follower's action frozen at its current value
    a2_fixed = agent.actor.apply(st.actors[1],
                                 jnp.concatenate([obs[:, 1], agent.actor.apply(st.actors[0], obs[:, 0])], -1))

    def frozen(theta1):
        a1 = agent.actor.apply(theta1, obs[:, 0])
        q = _critic_ref(agent, st.critics, 0, 0, obs, a1, a2_fixed)
        g = _critic_ref(agent, st.critics, 0, 1, obs, a1, a2_fixed)
        return jnp.mean(-q + lam[0] * (g - agent.config.cost_threshold[0]))

    np.testing.assert_allclose(g_naive, _fd_grad(frozen, st.actors[0]), rtol=1e-5, atol=1e-8)


@pytest.mark.parametrize("critic_input", [pytest.param("joint", marks=pytest.mark.slow), "own"])  # one default
def test_column_layout_networks_are_the_same_functions_with_the_same_gradients(critic_input, x64):
    """The update's column-layout critics and actors (jaxsmarl.columns) against the stacked einsum critics and
    the flax actor: values and every parameter's and input's gradient, float64, reference-sized networks."""
    agent = _agent(hidden_sizes=(64, 64, 64), critic_input=critic_input)
    st = jax.tree.map(lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x,
                      agent.init(jax.random.PRNGKey(3)))
    obs = jax.random.normal(jax.random.PRNGKey(4), (300, 2, D))
    act = jax.random.uniform(jax.random.PRNGKey(5), (300, 2, 1), jnp.float64, -1, 1)
    x = agent.critic_input(obs, act[:, 0], act[:, 1])
    w = jax.random.normal(jax.random.PRNGKey(6), (300, 2, 2))
    np.testing.assert_allclose(critic_values_columns(st.critics, x), critic_values(st.critics, x), rtol=1e-12,
                               atol=1e-12)
    loss = lambda f: (lambda p, x: jnp.sum(w * jnp.tanh(f(p, x))))
    for a, b in zip(jax.tree.leaves(jax.grad(loss(critic_values), (0, 1))(st.critics, x)),
                    jax.tree.leaves(jax.jit(jax.grad(loss(critic_values_columns), (0, 1)))(st.critics, x))):
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-12)
    x2 = jnp.concatenate([obs[:, 1], act[:, 0]], -1)
    theta2 = st.actors[1]
    np.testing.assert_allclose(actor_columns(theta2, x2, 1.0), agent.actor.apply(theta2, x2), rtol=1e-12, atol=1e-12)
    ref = jax.grad(lambda p, x: jnp.sum(jnp.sin(3.0 * agent.actor.apply(p, x))), (0, 1))(theta2, x2)
    col = jax.grad(lambda p, x: jnp.sum(jnp.sin(3.0 * actor_columns(p, x, 1.0))), (0, 1))(theta2, x2)
    for a, b in zip(jax.tree.leaves(ref), jax.tree.leaves(col)):
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-12)


def test_update_is_the_same_in_both_layouts(monkeypatch):
    """One update (constrained, Stackelberg, sequential actor order) with the column-layout networks (XLA:CPU) and
    with the row layout (other backends) gives the same new state."""
    ks = jax.random.split(jax.random.PRNGKey(4), 4)
    batch = Transition(obs=jax.random.normal(ks[0], (64, 2, D)), action=jax.random.uniform(ks[1], (64, 2, 1)),
                       reward=jax.random.normal(ks[2], (64, 2)), cost=jax.random.uniform(ks[3], (64, 2)),
                       next_obs=jax.random.normal(ks[1], (64, 2, D)), terminated=jnp.zeros((64, 2), bool),
                       truncated=jnp.zeros((64,), bool))
    out = {}
    for flag in (True, False):
        monkeypatch.setenv(ENV_VAR, "columns" if flag else "rows")
        agent = _agent(hidden_sizes=(64, 64, 64), actor_order="sequential")
        st = agent.init(jax.random.PRNGKey(3))
        out[flag] = jax.jit(agent.update)(st, batch, jax.random.PRNGKey(0))
        # the row layout (GPU) uses no column layer anywhere; the column layout (CPU) uses them
        assert ("custom_vjp" in str(jax.make_jaxpr(agent.update)(st, batch, jax.random.PRNGKey(0)))) == flag
    for a, b in zip(jax.tree.leaves(out[True]), jax.tree.leaves(out[False])):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)


def test_follower_gradient_through_a2_only_and_no_cross_terms(setup):
    agent, st, obs, lam = setup
    grads = jax.grad(lambda a: jnp.sum(agent.actor_losses(a, st.critics, lam, obs)[0]))(st.actors)
    a1 = agent.actor.apply(st.actors[0], obs[:, 0])
    d2 = agent.config.cost_threshold[1]

    def follower(theta2):  # the leader's action is given: theta2 acts through a2 only (p25)
        a2 = agent.actor.apply(theta2, jnp.concatenate([obs[:, 1], a1], -1))
        q = _critic_ref(agent, st.critics, 1, 0, obs, a1, a2)
        g = _critic_ref(agent, st.critics, 1, 1, obs, a1, a2)
        return jnp.mean(-q + lam[1] * (g - d2))

    np.testing.assert_allclose(ravel_pytree(grads[1])[0], _fd_grad(follower, st.actors[1]), rtol=1e-5, atol=1e-8)
    # the summed losses give theta1 exactly the leader's gradient: the follower's objective adds nothing to it
    fd_leader = _fd_grad(_leader_objective(agent, lam, obs, st.critics, st.actors[1]), st.actors[0])
    np.testing.assert_allclose(ravel_pytree(grads[0])[0], fd_leader, rtol=1e-5, atol=1e-8)
    # critic parameters get no gradient from the actor losses
    gc = jax.grad(lambda c: jnp.sum(agent.actor_losses(st.actors, c, lam, obs)[0]))(st.critics)
    assert all(float(jnp.abs(x).max()) == 0.0 for x in jax.tree.leaves(gc))


def test_plain_maddpg_follower_ignores_the_leader(x64):
    agent = _agent(stackelberg=False, constrained=False, critic_input="own")
    st = agent.init(jax.random.PRNGKey(0))
    assert ravel_pytree(st.actors[1])[0].size == ravel_pytree(st.actors[0])[0].size  # both read 8 inputs
    obs = jax.random.normal(jax.random.PRNGKey(1), (4, 2, D))
    a = agent.greedy_act(st, obs)
    np.testing.assert_allclose(a[:, 1], agent.actor.apply(st.actors[1], obs[:, 1]))
    lam = jnp.zeros(2)
    g = lambda t: ravel_pytree(
        jax.grad(lambda x: agent.actor_losses(x, st.critics, lam, obs, t)[0][0])(st.actors)[0])[0]
    np.testing.assert_allclose(g(True), g(False))  # no path through mu2 exists
    v = agent.actor_values(st.actors, st.critics, obs)
    np.testing.assert_allclose(v[:, 1, 0], _critic_ref(agent, st.critics, 1, 0, obs, a[:, 0], a[:, 1]), rtol=1e-10)


@pytest.mark.parametrize("boot_trunc", [True, False])
def test_td_targets_use_target_actors_at_next_state_and_own_termination(x64, boot_trunc):
    agent = _agent(bootstrap_on_truncation=boot_trunc, critic_input="own")
    st = agent.init(jax.random.PRNGKey(0))
    k = jax.random.split(jax.random.PRNGKey(1), 4)
    shifted = jax.tree.map(lambda x: x + 0.1, st)  # make targets differ from the online networks
    st = st.replace(target_actors=shifted.target_actors, target_critics=shifted.target_critics)
    b = 5
    batch = Transition(obs=jax.random.normal(k[0], (b, 2, D)), action=jax.random.uniform(k[1], (b, 2, 1), minval=-1),
                       reward=jax.random.normal(k[2], (b, 2)), cost=jax.random.uniform(k[3], (b, 2)),
                       next_obs=jax.random.normal(k[3], (b, 2, D)),
                       terminated=jnp.array([[0, 0], [1, 0], [0, 1], [1, 1], [0, 0]], bool),
                       truncated=jnp.array([0, 0, 0, 0, 1], bool))
    y = np.asarray(agent.td_targets(st, batch))
    a1 = agent.actor.apply(st.target_actors[0], batch.next_obs[:, 0])
    a2 = agent.actor.apply(st.target_actors[1], jnp.concatenate([batch.next_obs[:, 1], a1], -1))
    for i in range(2):
        done = np.asarray(batch.terminated[:, i]) | (np.asarray(batch.truncated) & (not boot_trunc))
        for kind, rc in ((0, batch.reward), (1, batch.cost)):
            boot = _critic_ref(agent, st.target_critics, i, kind, batch.next_obs, a1, a2)
            np.testing.assert_allclose(y[:, i, kind], rc[:, i] + 0.95 * (1 - done) * boot, rtol=1e-10)


def test_soft_update_period_and_multiplier_in_update():
    agent = _agent(lr_lambda=0.5, tau=0.01, target_update_every=3)
    st = agent.init(jax.random.PRNGKey(0))
    batch = jax.tree.map(lambda x: jnp.ones((8,) + x.shape, x.dtype), agent.transition_example())
    upd = jax.jit(agent.update)
    prev = st
    for n in range(4):
        new, info = upd(prev, batch, jax.random.PRNGKey(n))
        flat = lambda t: ravel_pytree(t)[0]
        if n in (0, 1, 2):  # updates 0..2 keep the targets (update 0 is excluded, as the authors')
            np.testing.assert_array_equal(flat(new.target_critics), flat(prev.target_critics))
        else:  # update 3: theta' <- 0.99 theta' + 0.01 theta, for critics and actors
            for tgt, old, online in ((new.target_critics, prev.target_critics, new.critics),
                                     (new.target_actors, prev.target_actors, new.actors)):
                np.testing.assert_allclose(flat(tgt), 0.99 * flat(old) + 0.01 * flat(online), rtol=1e-5, atol=1e-7)
        g_hat = np.asarray(info["g_actor"])  # dual ascent from the batch cost estimate at the actors' actions
        d = np.array(agent.config.cost_threshold)
        np.testing.assert_allclose(new.lam, np.clip(np.asarray(prev.lam) + 0.5 * (g_hat - d), 0, 100), rtol=1e-5,
                                   atol=1e-6)
        prev = new
    assert int(prev.n_updates) == 4


@pytest.mark.slow  # tests/test_maddpg_hierarchy.py checks the sequential order agent by agent by default
def test_sequential_actor_order_steps_the_follower_against_the_stepped_leader(x64):
    """actor_order="sequential" (authors' leader.train() then follower.train()): the leader's step and every critic
    step are those of the simultaneous update; the follower's actor takes one Adam step on its p25 loss with
    a1 = mu1(o1) of the STEPPED leader, and its multiplier uses G2 there (reference built here from the modules)."""
    import optax

    kw = dict(lr_actor=0.05, lr_lambda=0.5)
    sim, seq = _agent(**kw), _agent(actor_order="sequential", **kw)
    st = jax.tree.map(lambda x: x.astype(jnp.float64) if x.dtype == jnp.float32 else x, sim.init(jax.random.PRNGKey(5)))
    st = st.replace(lam=jnp.array([0.4, 0.9]))
    ex = sim.transition_example()
    batch = jax.tree.map(lambda x: jax.random.normal(jax.random.PRNGKey(6), (7,) + x.shape).astype(
        jnp.float64) if x.dtype != bool else jnp.zeros((7,) + x.shape, bool), ex)
    new_sim, _ = sim.update(st, batch, jax.random.PRNGKey(0))
    new_seq, info = seq.update(st, batch, jax.random.PRNGKey(0))
    flat = lambda t: np.asarray(ravel_pytree(t)[0])
    np.testing.assert_array_equal(flat(new_seq.actors[0]), flat(new_sim.actors[0]))
    np.testing.assert_array_equal(flat(new_seq.critics), flat(new_sim.critics))
    assert float(new_seq.lam[0]) == float(new_sim.lam[0])

    obs, d2 = batch.obs, sim.config.cost_threshold[1]
    a1_new = sim.actor.apply(new_sim.actors[0], obs[:, 0])

    def follower_values(theta2):
        a2 = sim.actor.apply(theta2, jnp.concatenate([obs[:, 1], a1_new], -1))
        return (_critic_ref(sim, st.critics, 1, 0, obs, a1_new, a2),
                _critic_ref(sim, st.critics, 1, 1, obs, a1_new, a2))

    def follower_loss(theta2):
        q, g = follower_values(theta2)
        return jnp.mean(-q + st.lam[1] * (g - d2))

    theta2 = st.actors[1]
    adam = optax.adam(kw["lr_actor"])
    step, _ = adam.update(jax.grad(follower_loss)(theta2), adam.init(theta2), theta2)
    np.testing.assert_allclose(flat(new_seq.actors[1]), flat(optax.apply_updates(theta2, step)), rtol=1e-9, atol=1e-12)
    g2 = float(jnp.mean(follower_values(theta2)[1]))
    np.testing.assert_allclose(float(new_seq.lam[1]), np.clip(0.9 + 0.5 * (g2 - d2), 0, 100), rtol=1e-9)
    np.testing.assert_allclose(float(info["g_actor"][1]), g2, rtol=1e-9)
    assert float(info["actor_loss"][1]) == pytest.approx(float(follower_loss(theta2)), rel=1e-9)
    # and it is a different update from the simultaneous one
    assert not np.allclose(flat(new_seq.actors[1]), flat(new_sim.actors[1]), rtol=1e-6, atol=1e-9)


@pytest.mark.parametrize("stackelberg", [True, False])
def test_greedy_preactivations_are_the_actions_before_tanh(stackelberg):
    agent = _agent(stackelberg=stackelberg, hidden_sizes=(5, 7), max_action=2.0)
    st = agent.init(jax.random.PRNGKey(0))
    obs = jax.random.normal(jax.random.PRNGKey(1), (6, 2, D))
    z = agent.greedy_preactivations(st.actors, obs)
    np.testing.assert_allclose(2.0 * np.tanh(z), agent.greedy_act(st, obs), atol=1e-6)
    # a leader whose last layer is scaled up saturates: its pre-activation scales, its action sticks at the bound
    big = jax.tree.map(lambda x: x, st.actors[0])
    big["params"]["_Dense_2"] = jax.tree.map(lambda x: 1e3 * x, big["params"]["_Dense_2"])
    z_big = agent.greedy_preactivations((big, st.actors[1]), obs)
    np.testing.assert_allclose(z_big[:, 0], 1e3 * z[:, 0], rtol=1e-5)
    assert np.all(np.abs(agent.greedy_act(st.replace(actors=(big, st.actors[1])), obs)[:, 0]) > 2.0 - 1e-3)


def test_exploration_schedule_and_greedy_limit():
    agent = MADDPGAgent(MADDPGConfig(noise_min=(0.0, 0.05), eps_min=(0.02, 0.0)))
    ex = agent.exploration(jnp.int32(150000))
    np.testing.assert_allclose(ex["noise"], [0.1 - 0.075, 0.05], rtol=1e-6)
    np.testing.assert_allclose(ex["eps"], [0.025, 0.025], rtol=1e-6)
    ex = agent.exploration(jnp.int32(10**6))
    np.testing.assert_allclose(ex["noise"], [0.0, 0.05])
    np.testing.assert_allclose(ex["eps"], [0.02, 0.0])
    st = agent.init(jax.random.PRNGKey(0))
    obs = jax.random.normal(jax.random.PRNGKey(1), (7, 2, D))
    zero = {"eps": jnp.zeros(2), "noise": jnp.zeros(2)}
    np.testing.assert_allclose(agent.act(st, obs, jax.random.PRNGKey(2), zero), agent.greedy_act(st, obs))
    wild = {"eps": jnp.array([0.5, 0.5]), "noise": jnp.array([10.0, 10.0])}
    a = agent.act(st, obs, jax.random.PRNGKey(2), wild)
    assert a.shape == (7, 2, 1) and float(jnp.abs(a).max()) <= 1.0


def test_toy_problem_td_error_falls_and_actors_reach_the_stackelberg_optimum():
    """One-step game (every transition terminal): r1 = -(a1 - 0.5)^2, r2 = -(a2 - a1/2)^2. Critics must fit the
    rewards (TD error -> 0) and the actors must reach the closed-form Stackelberg solution a1 = 0.5, a2 = a1/2."""
    agent = MADDPGAgent(MADDPGConfig(hidden_sizes=(32, 32), constrained=False, lr_actor=3e-3, lr_critic=3e-3,
                                     target_update_every=1, tau=0.05))
    st = agent.init(jax.random.PRNGKey(0))
    n = 2048
    k = jax.random.split(jax.random.PRNGKey(1), 2)
    obs = jax.random.normal(k[0], (n, 2, D)) * 0.1
    act = jax.random.uniform(k[1], (n, 2, 1), minval=-1, maxval=1)
    rew = jnp.stack([-(act[:, 0, 0] - 0.5) ** 2, -(act[:, 1, 0] - act[:, 0, 0] / 2) ** 2], -1)
    data = Transition(obs=obs, action=act, reward=rew, cost=jnp.zeros((n, 2)), next_obs=obs,
                      terminated=jnp.ones((n, 2), bool), truncated=jnp.zeros((n,), bool))

    def step(s, kk):
        idx = jax.random.randint(kk, (128,), 0, n)
        s, info = agent.update(s, jax.tree.map(lambda x: x[idx], data), kk)
        return s, info["loss_q"].sum()

    run = jax.jit(lambda s, kk: jax.lax.scan(step, s, jax.random.split(kk, 1500)))
    st, losses = run(st, jax.random.PRNGKey(2))
    assert float(losses[-100:].mean()) < 0.05 * float(losses[:10].mean())
    a = agent.greedy_act(st, obs[:64])
    np.testing.assert_allclose(a[:, 0, 0], 0.5, atol=0.08)
    np.testing.assert_allclose(a[:, 1, 0], a[:, 0, 0] / 2, atol=0.08)


# ---------------------------------------------------------------------------------------------------------------
def test_registry_defaults_and_configs():
    cs = load_config("intersection", "cs-maddpg")
    assert (cs["lr_actor"], cs["lr_critic"], cs["gamma"], cs["tau"], cs["batch_size"], cs["warmup"]) == (
        1e-4, 1e-3, 0.95, 0.01, 256, 512)
    assert cs["cost_threshold"] == [5.0, 5.0] and cs["lambda_max"] == 100.0 and cs["total_steps"] == 20000
    assert cs["noise_min"] == [0.0, 0.0]
    rt = load_config("racetrack", "cs-maddpg")
    assert rt["cost_threshold"] == [1.0, 1.0] and rt["total_steps"] == 500000
    s = load_config("racetrack", "s-maddpg")
    assert "cost_threshold" not in s and s["eps_min"] == [0.05, 0.05]
    for algo in ("c-maddpg", "maddpg"):
        load_config("intersection", algo)


@pytest.mark.parametrize("scenario, algo, over, msg", [
    ("merge", "cs-maddpg", {}, "continuous actions"),
    ("intersection", "s-maddpg", {"cost_threshold": 1.0}, "is a key of .*cs-maddpg"),
    ("intersection", "cs-maddpg", {"lambda_rule": "pid"}, "lambda_rule"),
    ("intersection", "cs-maddpg", {"lambda_init": 5.0, "lambda_max": 1.0}, "lambda_init"),
    ("intersection", "cs-maddpg", {"noise_start": -0.1}, "noise_start"),
    ("intersection", "maddpg", {"eps_min": [0.1, 2.0]}, "probabilities"),
    ("intersection", "maddpg", {"critic_input": "global"}, "critic_input"),
    ("racetrack", "cs-maddpg", {"lr_actor": 0.0}, "lr_actor"),
    ("racetrack", "maddpg", {"batch_size": 300, "total_steps": 200}, "batch_size"),
])
def test_validation_errors(scenario, algo, over, msg):
    with pytest.raises(ValueError, match=msg):
        load_config(scenario, algo, over)


def test_config_errors_before_jax():
    with pytest.raises(ValueError, match="critic_input"):
        MADDPGConfig(critic_input="x")
    with pytest.raises(ValueError, match="one value per agent"):
        MADDPGConfig(cost_threshold=(1.0,))


@pytest.mark.slow
def test_short_training_run_end_to_end(tmp_path):
    from train.run import run

    cfg = load_config("intersection", "cs-maddpg", dict(num_seeds=2, total_steps=800, chunk_steps=400,
                                                        checkpoint_every=400, eval_episodes=2, warmup=300,
                                                        batch_size=32, hidden_sizes=[16]))
    res = run(cfg, str(tmp_path / "r"), verbose=False)
    st = res["state"].agent
    assert int(st.n_updates[0]) == 800 - 300 + 1
    assert np.all(np.isfinite(ravel_pytree(st.actors)[0]))
    assert res["summary"]["finished"] and "eval" in res["summary"]
    assert (tmp_path / "r" / "summary.json").exists()


def test_actor_saturation_report_on_a_saved_run(tmp_path):
    """benchmarks/actor_saturation.py on a tiny racetrack run: at the reset states the largest |greedy action| is
    tanh of the largest |pre-activation| it reports, per seed and agent; its flag follows the threshold."""
    from train.build import make_train
    from train.run import run

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
    from actor_saturation import saturation

    cfg = load_config("racetrack", "s-maddpg", dict(num_seeds=2, total_steps=200, chunk_steps=100,
                                                    checkpoint_every=100, eval_episodes=0, warmup=100,
                                                    batch_size=16, hidden_sizes=[8]))
    st = run(cfg, str(tmp_path / "r"), verbose=False)["state"].agent
    rows = saturation(str(tmp_path / "r"), starts=3)
    trainer = make_train(cfg)
    obs, _ = jax.vmap(trainer.env.reset, in_axes=(0, None))(jax.random.split(jax.random.PRNGKey(0), 3),
                                                            trainer.env.default_params)
    assert len(rows) == 2
    for s_, row in enumerate(rows):
        actors = jax.tree.map(lambda x: x[s_], st.actors)
        a = np.asarray(jax.vmap(trainer.agent.joint_action, in_axes=(None, 0))(actors, obs), np.float64)
        np.testing.assert_allclose(np.tanh(row["max_abs"]), np.abs(a).max(axis=(0, 2)), atol=1e-6)
        assert row["saturated"] == bool(max(row["max_abs"]) > 3.0) and row["env_steps"] == 200
    with pytest.raises(ValueError, match="--starts"):
        saturation(str(tmp_path / "r"), starts=0)
