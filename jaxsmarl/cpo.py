"""Constrained policy optimisation step (Achiam et al. 2017) as MACPO codes it (docs/algorithms.md, MACPO), branch-free.

* :func:`fisher_vector_product`: ``(H + damping I) v`` with ``H`` the Hessian of the mean KL at the current
  parameters, by forward-over-reverse differentiation (``jvp`` of ``grad``); the reference adds ``0.1 v``.
  :func:`gauss_newton_operator`: the same product as ``J^T H_out J`` with the network linearised once (MACPO's).
* :func:`conjugate_gradient`: ``H^-1 b`` in ``iters`` steps (``lax.fori_loop``; the reference stops early when
  ``r.r < 1e-10``, reproduced by freezing the iterate).
* :func:`cpo_direction`: the five-case dual solution (``optim_case`` 0..4) with the reference's EPS
  substitutions, as ``jnp.where`` selections between closed forms.
* :func:`line_search`: every candidate ``theta - fraction_coef * fraction^i * x`` (``x`` rescaled to norm <= 0.5)
  evaluated at once (``vmap``); the first accepted one is taken, otherwise the parameters are kept.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp

__all__ = ["fisher_vector_product", "gauss_newton_operator", "conjugate_gradient", "cpo_direction", "first_accepted",
           "line_search"]

EPS = 1e-8


def fisher_vector_product(kl_fn: Callable, theta, v, damping: float = 0.1):
    """``Hessian(kl_fn)(theta) @ v + damping * v`` (forward-over-reverse)."""
    return jax.jvp(jax.grad(kl_fn), (theta,), (v,))[1] + damping * v


def gauss_newton_operator(outputs_fn: Callable, out_kl_fn: Callable, theta, damping: float = 0.1,
                          reverse_fn: Callable | None = None) -> Callable:
    """``v -> J^T H_out J v + damping * v``: the KL's Hessian in the form ``J`` (Jacobian of the network outputs
    ``outputs_fn(theta)``) then ``H_out`` (Hessian of ``out_kl_fn`` in the outputs, by forward-over-reverse on
    the outputs only) then ``J^T``.

    At the reference point of the KL (the old policy's outputs equal ``outputs_fn(theta)``) the KL's gradient
    in the outputs vanishes, so this is the Hessian of ``out_kl_fn(outputs_fn(theta))`` exactly, i.e. what
    :func:`fisher_vector_product` computes. The network is linearised once (one forward pass shared by all
    products), and a product costs one tangent pass and one backward pass of the network, instead of
    differentiating its backward pass forward-mode.

    ``J^T`` is the transpose of the linearisation, or, with ``reverse_fn`` (the same function of ``theta`` written
    for a faster reverse mode, e.g. :func:`jaxsmarl.mlp.mlp_rows`), its ``jax.vjp`` at ``theta``.
    """
    out, jvp_fn = jax.linearize(outputs_fn, theta)
    vjp_fn = jax.linear_transpose(jvp_fn, theta) if reverse_fn is None else jax.vjp(reverse_fn, theta)[1]

    def hess_out(t):
        return jax.jvp(jax.grad(out_kl_fn), (out,), (t,))[1]

    return lambda v: vjp_fn(hess_out(jvp_fn(v)))[0] + damping * v


def conjugate_gradient(avp: Callable, b, iters: int = 10, residual_tol: float = 1e-10):
    """Solve ``A x = b`` for symmetric positive-definite ``A`` given ``avp(p) = A p`` (the reference's CG)."""

    def body(_, c):
        x, r, p, rdotr, stop = c
        ap = avp(p)
        alpha = rdotr / (jnp.dot(p, ap) + 1e-8)
        x_new = x + alpha * p
        r_new = r - alpha * ap
        new_rdotr = jnp.dot(r_new, r_new)
        p_new = r_new + new_rdotr / rdotr * p
        keep = lambda old, new: jnp.where(stop, old, new)
        return (keep(x, x_new), keep(r, r_new), keep(p, p_new), keep(rdotr, new_rdotr),
                stop | (new_rdotr < residual_tol))

    init = (jnp.zeros_like(b), b, b, jnp.dot(b, b), jnp.zeros((), bool))
    return jax.lax.fori_loop(0, iters, body, init)[0]


def cpo_direction(g, b, hinv_g, hinv_b, c, kl_threshold: float):
    """The step direction ``x`` (parameters move to ``theta - step * x``) and ``(case, lam, nu)``.

    ``g``: gradient of the reward loss ``-E[ratio * factor * A_r]``; ``b``: gradient of the cost surrogate
    ``E[ratio * factor * A_c]``; ``hinv_*``: their CG solutions; ``c = (J_c - d)(1 - gamma)`` (already with the
    reference's ``0 -> EPS``). Cases (``optim_case``): 4 ``b.b <= EPS`` and ``c < 0`` (TRPO step); 3 ``c < 0``,
    ``B < 0`` (TRPO step); 2 ``c < 0``, ``B >= 0`` and 1 ``c >= 0``, ``B >= 0`` (dual with projections);
    0 ``c >= 0``, ``B < 0`` (recovery ``x = nu H^-1 b``), with ``q = g.H^-1 g``, ``r = g.H^-1 b``,
    ``s = b.H^-1 b``, ``B = 2 delta - c^2 / s``.
    """
    delta = kl_threshold
    case4 = (jnp.dot(b, b) <= EPS) & (c < 0)
    hinv_b = jnp.where(case4, jnp.zeros_like(hinv_b), hinv_b)
    q = jnp.dot(g, hinv_g)
    r = jnp.dot(g, hinv_b)
    s = jnp.dot(b, hinv_b)
    r = jnp.where(case4, 0.0, jnp.where(r == 0, EPS, r))
    s = jnp.where(case4, 0.0, jnp.where(s == 0, EPS, s))
    a_val = jnp.where(case4, 0.0, q - r ** 2 / (EPS + s))  # positive_Cauchy_value
    b_val = jnp.where(case4, 0.0, 2 * delta - c ** 2 / (EPS + s))  # whether_recover_policy_value
    case = jnp.where(case4, 4, jnp.where(c < 0, jnp.where(b_val < 0, 3, 2), jnp.where(b_val >= 0, 1, 0)))
    b_val = jnp.where(b_val == 0, EPS, b_val)

    lam_trpo = jnp.sqrt(q / (2 * delta))
    # Cases 1, 2: lambda from the two projected candidates.
    rc = r / c
    inf = jnp.asarray(jnp.inf, rc.dtype)
    neg = c < 0
    la = (jnp.where(neg, 0.0, rc), jnp.where(neg, rc, inf))
    lb = (jnp.where(neg, rc, 0.0), jnp.where(neg, inf, rc))
    proj = lambda x, lo_hi: jnp.maximum(lo_hi[0], jnp.minimum(lo_hi[1], x))
    lam_a = proj(jnp.sqrt(jnp.maximum(a_val / b_val, 0.0)), la)
    lam_b = proj(lam_trpo, lb)
    f_a = -0.5 * (a_val / (EPS + lam_a) + b_val * lam_a) - r * c / (EPS + s)
    f_b = -0.5 * (q / (EPS + lam_b) + 2 * delta * lam_b)
    lam_12 = jnp.where(f_a >= f_b, lam_a, lam_b)
    nu_12 = jnp.maximum(0.0, lam_12 * c - r) / (EPS + s)

    lam = jnp.where(case >= 3, lam_trpo, jnp.where(case >= 1, lam_12, 0.0))
    nu = jnp.where(case >= 3, 0.0, jnp.where(case >= 1, nu_12, jnp.sqrt(2 * delta / (EPS + s))))
    x = jnp.where(case > 0, (hinv_g + nu * hinv_b) / (lam + EPS), nu * hinv_b)
    return x, case, lam, nu


def first_accepted(accept):
    """``(index of the first True, any True)`` of a boolean vector."""
    accept = jnp.asarray(accept, bool)
    return jnp.argmax(accept), jnp.any(accept)


def line_search(theta, x, evaluate: Callable, accept: Callable, steps: int = 10, fraction: float = 0.5,
                fraction_coef: float = 0.1, max_norm: float = 0.5):
    """Backtracking line search, all candidates at once.

    ``evaluate(theta_new) -> stats`` (a pytree of scalars), ``accept(stats) -> bool``. Returns
    ``(theta_new, accepted, index, stats of every candidate)``; ``theta`` is kept when nothing is accepted.
    """
    norm = jnp.linalg.norm(x)
    x = jnp.where(norm > max_norm, x * max_norm / jnp.where(norm > 0, norm, 1.0), x)
    scales = fraction_coef * fraction ** jnp.arange(steps, dtype=theta.dtype)
    candidates = theta[None] - scales[:, None] * x[None]
    stats = jax.vmap(evaluate)(candidates)
    ok = jax.vmap(accept)(stats)
    idx, found = first_accepted(ok)
    return jnp.where(found, candidates[idx], theta), found, idx, stats
