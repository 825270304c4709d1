"""Per-agent Lagrange multipliers for the constrained Stackelberg actors (paper eqs. p21, p22b/p22d, p24/p26).

The relaxed objective of agent i is ``L_i(theta_i, lambda_i) = Q_i - lambda_i (G_i - d_i)`` (p21), maximised over
the actor and minimised over ``lambda_i >= 0``. Two multiplier rules:

* ``"dual"`` (paper): projected dual ascent ``lambda <- clip(lambda + lr (G_hat - d), 0, lambda_max)`` with
  ``G_hat`` the batch mean of the cost critic at the current actors' actions (p22b/p22d with p24/p26, whose
  gradient is ``-(G - d)``; the printed extra factor lambda is a typo). lambda rises while the cost estimate exceeds
  d and falls when it is below. The actor's penalty is ``lambda (G - d)``. A small ``lr`` relative to the actors'
  gives the paper's slower timescale.
* ``"authors"`` (docs/algorithms.md, 'Lagrange multipliers'): ``lambda <- clip(lambda + lr mean(relu(G - d)), 0,
  lambda_max)``, a hinge increment that never decreases lambda, and the hinge penalty ``lambda relu(G - d)``.

Everything broadcasts over a trailing constraint / agent axis: ``lam`` ``[n]``, cost samples ``[..., n]``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

__all__ = ["RULES", "Lagrangian"]

RULES = ("dual", "authors")


@dataclasses.dataclass(frozen=True)
class Lagrangian:
    """Multiplier rule for ``n`` constraints with thresholds ``threshold`` ``[n]`` (static hyper-parameters)."""

    threshold: tuple[float, ...]
    lr: float = 1e-3
    lam_max: float = 100.0
    lam_init: float = 0.0
    rule: str = "dual"

    def __post_init__(self):
        if self.rule not in RULES:
            raise ValueError(f"unknown multiplier rule {self.rule!r}; choose one of {', '.join(RULES)}")
        if not self.lr >= 0:
            raise ValueError(f"multiplier learning rate must be >= 0, got {self.lr}")
        if not self.lam_max >= 0:
            raise ValueError(f"multiplier bound lam_max must be >= 0, got {self.lam_max}")
        if not 0 <= self.lam_init <= self.lam_max:
            raise ValueError(f"initial multiplier must lie in [0, lam_max={self.lam_max}], got {self.lam_init}")

    @property
    def n(self) -> int:
        return len(self.threshold)

    def _d(self) -> jax.Array:
        return jnp.asarray(self.threshold, dtype=jnp.result_type(float))

    def init(self) -> jax.Array:
        """``[n]`` initial multipliers."""
        return jnp.full((self.n,), self.lam_init, dtype=jnp.result_type(float))

    def violation(self, cost: jax.Array) -> jax.Array:
        """The ascent direction ``[n]`` from cost estimates ``[..., n]`` (mean over the leading axes):
        ``mean(G) - d`` (dual) or ``mean(relu(G - d))`` (authors)."""
        cost = jnp.asarray(cost)
        axes = tuple(range(cost.ndim - 1))
        if self.rule == "dual":
            return jnp.mean(cost, axis=axes) - self._d()
        return jnp.mean(jax.nn.relu(cost - self._d()), axis=axes)

    def update(self, lam: jax.Array, cost: jax.Array) -> jax.Array:
        """One projected ascent step ``clip(lam + lr * violation(cost), 0, lam_max)``; no gradient flows back."""
        step = jax.lax.stop_gradient(self.violation(cost))
        return jnp.clip(lam + self.lr * step, 0.0, self.lam_max).astype(lam.dtype)

    def penalty(self, lam: jax.Array, cost: jax.Array) -> jax.Array:
        """Per-sample actor penalty ``[..., n]``: ``lam (G - d)`` (dual, p21) or ``lam relu(G - d)`` (authors).
        ``lam`` is treated as a constant (the actors do not move the multiplier)."""
        lam = jax.lax.stop_gradient(lam)
        gap = cost - self._d()
        return lam * (gap if self.rule == "dual" else jax.nn.relu(gap))
