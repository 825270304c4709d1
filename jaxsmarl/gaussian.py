"""The diagonal Gaussian policy of MAPPO-L and MACPO (docs/algorithms.md, MAPPO-L and MACPO): a state-independent
bounded standard deviation ``std = sigmoid(log_std / x_coef) * y_coef`` (``log_std`` initialised to ``x_coef``),
log-densities, entropy and the KL divergence."""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

__all__ = ["std_from_param", "gaussian_log_prob", "gaussian_entropy", "gaussian_kl"]


def std_from_param(log_std, x_coef: float, y_coef: float):
    """``sigmoid(log_std / x_coef) * y_coef``: bounded in (0, y_coef)."""
    return jax.nn.sigmoid(log_std / x_coef) * y_coef


def gaussian_log_prob(action, mean, std):
    """Log-density of a diagonal Gaussian, summed over the last (action) axis."""
    z = (action - mean) / std
    return jnp.sum(-0.5 * z * z - jnp.log(std) - 0.5 * math.log(2.0 * math.pi), axis=-1)


def gaussian_entropy(std):
    return jnp.sum(0.5 + 0.5 * math.log(2.0 * math.pi) + jnp.log(std), axis=-1)


def gaussian_kl(mean_old, std_old, mean, std):
    """``KL(old || new) = log(s/s_old) + (s_old^2 + (m_old - m)^2) / (2 s^2) - 1/2`` summed over action dims
    (with the reference's 1e-8). safepo's ``kl_divergence`` writes ``log(s_old) - log(s)``, which is not a KL
    (its gradient in s does not vanish at s = s_old); we use the true divergence, whose Hessian there is the
    Fisher matrix."""
    kl = (jnp.log(std) - jnp.log(std_old) + (std_old ** 2 + (mean_old - mean) ** 2) / (1e-8 + 2.0 * std ** 2)
          - 0.5)
    return jnp.sum(kl, axis=-1)
