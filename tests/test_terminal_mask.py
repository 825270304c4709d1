"""The ``terminal_mask`` option of the off-policy learners (jaxsmarl.bootstrap).

``batch_mean`` must have the gradient of the authors' broadcast: their buffer returns rewards ``[B]`` and done
flags ``[B, 1]``, and their target ``r.unsqueeze(1) + gamma * (1 - t.unsqueeze(1)) * q_next`` broadcasts to
``[B, B, 1]`` before ``(target - q).pow(2).mean()``. The reference here is that expression in plain numpy, with
those shapes, differentiated by central differences (exact for a quadratic, up to rounding).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl import bootstrap
from train import config as train_config


def authors_loss(q, r, t, q_next, gamma):
    """Their critic loss, shapes as in their code: q [B, 1], r [B], t [B, 1], q_next [B, 1]."""
    target = r[:, None] + gamma * (1 - t[:, None]) * q_next  # [B, 1] + [B, 1, 1] * [B, 1] -> [B, B, 1]
    assert target.shape == (len(r), len(r), 1)
    return np.mean((target - q) ** 2)


def authors_grad(q, r, t, q_next, gamma, h=1e-6):
    g = np.zeros_like(q)
    for k in range(q.shape[0]):
        e = np.zeros_like(q)
        e[k, 0] = h
        g[k, 0] = (authors_loss(q + e, r, t, q_next, gamma) - authors_loss(q - e, r, t, q_next, gamma)) / (2 * h)
    return g


def our_grad(q, y):
    """Gradient of mean_k (q_k - y_k)^2, our critic loss, with respect to q."""
    return np.asarray(jax.grad(lambda qq: jnp.mean((qq - y) ** 2))(jnp.asarray(q[:, 0])))[:, None]


def test_choices_restated_in_the_config_match():
    assert train_config.TERMINAL_MASKS == bootstrap.TERMINAL_MASKS


@pytest.mark.parametrize("seed", range(3))
def test_batch_mean_has_the_gradient_of_the_authors_broadcast(seed):
    with jax.enable_x64(True):
        rng = np.random.default_rng(seed)
        B, gamma = 9, 0.95
        r, q_next, q = rng.normal(size=B), rng.normal(size=(B, 1)), rng.normal(size=(B, 1))
        term = rng.random(B) < 0.3
        trunc = rng.random(B) < 0.2
        t = (term | trunc).astype(np.float64)[:, None]  # their stored done includes the time limit
        keep = bootstrap.continuation(jnp.asarray(term[:, None]), jnp.asarray(trunc), "batch_mean",
                                      bootstrap_on_truncation=False, dtype=jnp.float64)[:, 0]
        y = r + gamma * np.asarray(keep) * q_next[:, 0]
        np.testing.assert_allclose(our_grad(q, y), authors_grad(q, r, t, q_next, gamma), rtol=1e-7, atol=1e-9)
        # the per-sample rule is a different function: its gradient differs once the batch mixes done flags
        keep_s = bootstrap.continuation(jnp.asarray(term[:, None]), jnp.asarray(trunc), "sample",
                                        bootstrap_on_truncation=False, dtype=jnp.float64)[:, 0]
        np.testing.assert_array_equal(np.asarray(keep_s), 1.0 - t[:, 0])
        y_s = r + gamma * np.asarray(keep_s) * q_next[:, 0]
        assert not np.allclose(our_grad(q, y_s), authors_grad(q, r, t, q_next, gamma), atol=1e-6)


def test_unknown_rule_is_refused():
    with pytest.raises(ValueError, match="terminal_mask must be one of sample, batch_mean"):
        bootstrap.continuation(jnp.zeros((2, 2), bool), jnp.zeros((2,), bool), "mean")


def _targets(agent, state, batch, key, eps):
    args = (key, eps) if hasattr(agent, "policy") else ()  # CSQ's target actions may explore; MADDPG's do not
    return np.asarray(agent.td_targets(state, batch, *args), np.float64)


def _agents(kind, **cfg):
    if kind == "csq":
        from jaxsmarl.algos.csq import CSQAgent, CSQConfig

        return CSQAgent(CSQConfig(obs_dim=4, hidden_sizes=(8,), **cfg)), (lambda a: a.epsilon(0))
    from jaxsmarl.algos.maddpg import MADDPGAgent, MADDPGConfig

    return MADDPGAgent(MADDPGConfig(obs_dim=4, hidden_sizes=(8,), **cfg)), (lambda a: a.exploration(0))


@pytest.mark.parametrize("kind", ["csq", "maddpg"])
def test_agents_targets_follow_the_authors_broadcast(kind):
    """Each learner's targets with ``batch_mean`` give, per agent and critic kind, the gradient of the authors'
    broadcast loss built from the same rewards, done flags and bootstrap values."""
    with jax.enable_x64(True):
        B, gamma = 12, 0.95
        agent, explore = _agents(kind, gamma=gamma, terminal_mask="batch_mean", bootstrap_on_truncation=False)
        plain, _ = _agents(kind, gamma=gamma)
        state = agent.init(jax.random.PRNGKey(1))
        ex = agent.transition_example()
        rng = np.random.default_rng(0)
        term = rng.random((B, 2)) < 0.35
        trunc = rng.random(B) < 0.25
        if kind == "csq":
            action = jnp.asarray(rng.integers(0, 5, (B, 2)), jnp.int32)
        else:
            action = jnp.asarray(rng.uniform(-1, 1, (B, 2, 1)))
        batch = type(ex)(obs=jnp.asarray(rng.normal(size=(B, 2, 4))), action=action,
                         reward=jnp.asarray(rng.normal(size=(B, 2))), cost=jnp.asarray(rng.random((B, 2))),
                         next_obs=jnp.asarray(rng.normal(size=(B, 2, 4))), terminated=jnp.asarray(term),
                         truncated=jnp.asarray(trunc))
        key, eps = jax.random.PRNGKey(2), explore(agent)
        y = _targets(agent, state, batch, key, eps)  # [B, 2, K]
        # bootstrap values Q'(s', a'): targets of the per-sample rule on the same batch with no done flags
        free = batch.replace(terminated=jnp.zeros_like(batch.terminated), truncated=jnp.zeros_like(batch.truncated))
        rc = np.stack([np.asarray(batch.reward), np.asarray(batch.cost)], -1)[..., : y.shape[-1]]
        q_next = (_targets(plain, state, free, key, eps) - rc) / gamma
        t = (term | trunc[:, None]).astype(np.float64)
        q = rng.normal(size=y.shape)
        for i in range(2):
            for k in range(y.shape[-1]):
                want = authors_grad(q[:, i, k][:, None], rc[:, i, k], t[:, i][:, None], q_next[:, i, k][:, None],
                                    gamma)
                np.testing.assert_allclose(our_grad(q[:, i, k][:, None], y[:, i, k]), want, rtol=1e-6, atol=1e-8)
