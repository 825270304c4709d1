"""CPO pieces: conjugate gradient, the Fisher-vector product, the five cases, the line search."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.flatten_util import ravel_pytree

from jaxsmarl import cpo
from jaxsmarl.algos.macpo import MACPO
from jaxsmarl.algos.ppo_base import PPOConfig
from jaxsmarl.gaussian import gaussian_kl
from jaxsmarl.losses import masked_mean
from jaxsmarl.mlp import mlp_rows


def test_conjugate_gradient_solves_spd_system(x64):
    rng = np.random.default_rng(0)
    n = 6
    a = rng.normal(size=(n, n))
    A = a @ a.T + n * np.eye(n)
    b = 1e3 * rng.normal(size=n)  # large enough that the reference's 1e-8 in alpha's denominator is negligible
    avp = lambda p: jnp.asarray(A) @ p
    exact = np.linalg.solve(A, b)
    # n iterations solve an n x n system; the reference stops once r.r < 1e-10 (residual ~1e-5).
    np.testing.assert_allclose(cpo.conjugate_gradient(avp, jnp.asarray(b), n, residual_tol=0.0), exact, rtol=1e-8)
    x = cpo.conjugate_gradient(avp, jnp.asarray(b), iters=10)
    np.testing.assert_allclose(x, exact, rtol=1e-6)


def test_fisher_vector_product_matches_closed_form_fisher():
    """At theta_old the KL Hessian of a Gaussian with state-independent std is the Fisher matrix
    ``mean_s [J_mu^T J_mu / sigma^2 + 2 J_logsigma^T J_logsigma]``, built here from forward-mode Jacobians."""
    with jax.enable_x64(True):
        agent = MACPO(PPOConfig(hidden=3, layer_n=0, action_dim=2, obs_dim=4))
        actor = jax.tree.map(lambda x: x[0], agent.init(jax.random.PRNGKey(0)).actor)
        actor = jax.tree.map(lambda x: x.astype(jnp.float64), actor)
        actor["log_std"] = jnp.array([0.3, -0.2])
        theta, unravel = ravel_pytree(actor)
        obs = jax.random.normal(jax.random.PRNGKey(1), (5, 4), jnp.float64)
        m0, s0 = jax.lax.stop_gradient(agent.policy(actor, obs))

        def kl(th):
            m, s = agent.policy(unravel(th), obs)
            return jnp.mean(gaussian_kl(m0, s0, m, jnp.broadcast_to(s, m.shape)))

        j_mu = jax.jacfwd(lambda th: agent.policy(unravel(th), obs)[0])(theta)  # [5, 2, P]
        j_ls = jax.jacfwd(lambda th: jnp.log(agent.policy(unravel(th), obs)[1]))(theta)  # [2, P]
        fisher = (np.einsum("bkp,bkq,k->pq", j_mu, j_mu, 1 / np.asarray(s0) ** 2) / 5
                  + 2 * np.einsum("kp,kq->pq", j_ls, j_ls))
        v = jax.random.normal(jax.random.PRNGKey(2), theta.shape, jnp.float64)
        fvp = cpo.fisher_vector_product(kl, theta, v, damping=0.1)
        np.testing.assert_allclose(fvp, fisher @ v + 0.1 * v, rtol=1e-5, atol=1e-9)
        # what MACPO uses: J^T H_out J with the network linearised once, for any vector
        kl_of = lambda out: jnp.mean(gaussian_kl(m0, s0, out[0], jnp.broadcast_to(out[1], out[0].shape)))
        op = jax.jit(lambda th, u: cpo.gauss_newton_operator(lambda t: agent.policy(unravel(t), obs), kl_of, th,
                                                             damping=0.1)(u))
        for u in (v, 2.0 * v + 1.0, jnp.zeros_like(v)):
            np.testing.assert_allclose(op(theta, u), fisher @ u + 0.1 * u, rtol=1e-5, atol=1e-9)


def test_gauss_newton_operator_is_the_kl_hessian_of_a_masked_minibatch():
    """MACPO's product (J^T H_out J) against forward-over-reverse on the whole KL, float32, a masked minibatch
    of a reference-sized actor (obs 8 -> 64 -> 64 -> 1)."""
    agent = MACPO(PPOConfig())
    actor = jax.tree.map(lambda x: x[0], agent.init(jax.random.PRNGKey(0)).actor)
    actor = jax.tree.map(lambda x: x + 0.05 * jax.random.normal(jax.random.PRNGKey(4), x.shape, x.dtype), actor)
    theta, unravel = ravel_pytree(actor)
    obs = jax.random.normal(jax.random.PRNGKey(1), (512, 8))
    mask = jax.random.uniform(jax.random.PRNGKey(3), (512,)) < 0.7
    m0, s0 = jax.lax.stop_gradient(agent.policy(actor, obs))
    kl_of = lambda out: masked_mean(gaussian_kl(m0, s0, out[0], jnp.broadcast_to(out[1], out[0].shape)), mask)
    policy_at = lambda t: agent.policy(unravel(t), obs)
    v = jax.random.normal(jax.random.PRNGKey(2), theta.shape)
    full = jax.jit(lambda u: cpo.fisher_vector_product(lambda t: kl_of(policy_at(t)), theta, u, 0.1))(v)
    gn = jax.jit(lambda u: cpo.gauss_newton_operator(policy_at, kl_of, theta, 0.1)(u))(v)
    np.testing.assert_allclose(gn, full, rtol=1e-4, atol=1e-6 * float(jnp.max(jnp.abs(full))))
    # J^T from a separate reverse-mode form of the network (MACPO on XLA:CPU: mlp_rows)
    rows_at = lambda t: (mlp_rows(unravel(t)["net"], obs), agent.policy(unravel(t), obs)[1])
    gn_rows = jax.jit(lambda u: cpo.gauss_newton_operator(policy_at, kl_of, theta, 0.1, reverse_fn=rows_at)(u))(v)
    np.testing.assert_allclose(gn_rows, full, rtol=1e-4, atol=1e-6 * float(jnp.max(jnp.abs(full))))


def reference_direction(g, b, hg, hb, c, delta, eps=1e-8):
    """The reference's trpo_update case analysis, in plain Python floats (docs/algorithms.md, MACPO)."""
    q = float(g @ hg)
    if float(b @ b) <= eps and c < 0:
        hb, r, s, A, B, case = 0 * hb, 0.0, 0.0, 0.0, 0.0, 4
    else:
        r, s = float(g @ hb), float(b @ hb)
        r = eps if r == 0 else r
        s = eps if s == 0 else s
        A = q - r ** 2 / (eps + s)
        B = 2 * delta - c ** 2 / (eps + s)
        case = 3 if (c < 0 and B < 0) else 2 if (c < 0 and B >= 0) else 1 if (c >= 0 and B >= 0) else 0
    if B == 0:
        B = eps
    if case in (3, 4):
        lam, nu = math.sqrt(q / (2 * delta)), 0.0
    elif case in (1, 2):
        LA, LB = [0, r / c], [r / c, math.inf]
        LA, LB = (LA, LB) if c < 0 else (LB, LA)
        proj = lambda x, L: max(L[0], min(L[1], x))
        lam_a = proj(math.sqrt(A / B), LA)
        lam_b = proj(math.sqrt(q / (2 * delta)), LB)
        f_a = lambda lam: -0.5 * (A / (eps + lam) + B * lam) - r * c / (eps + s)
        f_b = lambda lam: -0.5 * (q / (eps + lam) + 2 * delta * lam)
        lam = lam_a if f_a(lam_a) >= f_b(lam_b) else lam_b
        nu = max(0, lam * c - r) / (eps + s)
    else:
        lam, nu = 0.0, math.sqrt(2 * delta / (eps + s))
    x = (hg + nu * hb) / (lam + eps) if case > 0 else nu * hb
    return x, case, lam, nu


DELTA = 0.01
g0 = np.array([1.0, 0.5, -0.2])
CASES = {  # H = diag(h): hinv = v / h
    4: (g0, np.zeros(3), -0.1),  # zero cost gradient, feasible
    3: (g0, np.array([0.0, 0.1, 0.0]), -0.5),  # feasible, whole trust region safe (B < 0)
    2: (g0, np.array([0.3, 1.0, 0.2]), -0.05),  # feasible, boundary cuts the trust region
    1: (g0, np.array([0.3, 1.0, 0.2]), 0.05),  # infeasible but recoverable
    0: (g0, np.array([0.0, 0.1, 0.0]), 0.5),  # infeasible: recovery step
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_cpo_case_gives_the_closed_form_step(case, x64):
    g, b, c = CASES[case]
    h = np.array([1.0, 2.0, 0.5])
    hg, hb = g / h, b / h
    x, got_case, lam, nu = jax.jit(cpo.cpo_direction, static_argnums=5)(g, b, hg, hb, c, DELTA)
    x_ref, case_ref, lam_ref, nu_ref = reference_direction(g, b, hg, hb, c, DELTA)
    assert case_ref == case and int(got_case) == case
    np.testing.assert_allclose(x, x_ref, rtol=1e-9)
    np.testing.assert_allclose([lam, nu], [lam_ref, nu_ref], rtol=1e-9, atol=1e-12)
    if case in (3, 4):  # plain TRPO step: on the trust-region boundary, x^T H x = 2 delta
        np.testing.assert_allclose(x @ (h * x), 2 * DELTA, rtol=1e-6)
    if case == 0:  # pure recovery along H^-1 b with b^T x = sqrt(2 delta s)
        np.testing.assert_allclose(x, math.sqrt(2 * DELTA / (b @ hb)) * hb, rtol=1e-6)


def test_line_search_takes_first_accepted_candidate():
    theta = jnp.array([1.0, 0.0])
    x = jnp.array([2.0, 0.0])  # rescaled to norm 0.5; candidates 1 - 0.1 * 0.5^i * 0.5
    accept = lambda s: s["v"] > 0.99  # candidates 0.95, 0.975, 0.9875, 0.99375, ...: accepted from i = 3 on
    new, found, idx, stats = cpo.line_search(theta, x, lambda th: {"v": th[0]}, accept, steps=10, fraction=0.5,
                                             fraction_coef=0.1)
    vals = 1.0 - 0.1 * 0.5 ** np.arange(10) * 0.5
    first = int(np.flatnonzero(vals > 0.99)[0])
    assert bool(found) and int(idx) == first == 3
    np.testing.assert_allclose(new, [vals[first], 0.0], rtol=1e-6)
    np.testing.assert_allclose(stats["v"], vals, rtol=1e-6)
    new, found, _, _ = cpo.line_search(theta, x, lambda th: {"v": th[0]}, lambda s: s["v"] > 2.0)
    assert not bool(found)
    np.testing.assert_array_equal(new, theta)
