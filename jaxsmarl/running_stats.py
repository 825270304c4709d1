"""Running mean and variance (Chan et al.'s parallel update), for the observation normalisation and the
value-target normalisation of MAPPO-L and MACPO (the reference's ValueNorm; one per critic here instead of the
reference's shared reward normaliser, a documented deviation, docs/algorithms.md)."""

from __future__ import annotations

import flax.struct
import jax
import jax.numpy as jnp

__all__ = ["RunningStats"]


@flax.struct.dataclass
class RunningStats:
    """Running mean and variance over a batch axis, per element of ``mean.shape``."""

    count: jax.Array
    mean: jax.Array
    var: jax.Array

    @classmethod
    def create(cls, shape, dtype=None):
        dtype = dtype or jnp.zeros(()).dtype
        return cls(jnp.zeros(shape, dtype), jnp.zeros(shape, dtype), jnp.ones(shape, dtype))

    def update(self, x, mask=None):
        """Merge the samples ``x[..., *shape]`` (leading axes are samples). ``mask`` (per sample, or per
        element like ``x``) selects what is merged; counts are kept per element."""
        lead = x.ndim - self.mean.ndim
        axes = tuple(range(lead))
        w = jnp.ones(x.shape, x.dtype) if mask is None else jnp.asarray(mask, x.dtype)
        w = jnp.broadcast_to(w.reshape(w.shape + (1,) * (x.ndim - w.ndim)), x.shape)
        n = jnp.sum(w, axis=axes)
        n_b = jnp.maximum(n, 1.0)
        m_b = jnp.sum(w * x, axis=axes) / n_b
        v_b = jnp.sum(w * (x - m_b) ** 2, axis=axes) / n_b
        tot = self.count + n
        frac = n / jnp.maximum(tot, 1.0)
        delta = m_b - self.mean
        mean = self.mean + delta * frac
        m2 = self.var * self.count + v_b * n + delta ** 2 * self.count * frac
        var = jnp.where(tot > 0, m2 / jnp.maximum(tot, 1.0), self.var)
        return RunningStats(tot, mean, var)

    def normalize(self, x, clip: float = 10.0):
        y = (x - self.mean) / jnp.sqrt(self.var + 1e-8)
        return jnp.clip(y, -clip, clip)

    def denormalize(self, y):
        return y * jnp.sqrt(self.var + 1e-8) + self.mean
