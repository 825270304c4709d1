"""The simulator's trigonometry: ``sin``, ``cos``, ``tan``, ``arctan``, ``arctan2`` and ``arcsin``.

In float64 these are XLA's own functions (the parity suites compare highway-env's numpy digits bit for bit).
In float32 they are polynomials in plain arithmetic (the single-precision Cephes approximations: a Cody-Waite
reduction by pi/2 for the circular functions, the tan(pi/8) split for the arc tangent), which XLA vectorises on
every backend; XLA:CPU evaluates its own trigonometric functions one element at a time, 7-25 ns each against
about 1 ns. Each float32 result is computed once into a buffer (:func:`~envs_jax.materialize.materialize`): XLA
counts the polynomials as cheap and would otherwise repeat a whole chain of them inside every fusion that reads it,
which made the step slower than XLA's own functions (docs/performance.md, "Trigonometry in plain arithmetic").
Their error is a few float32 ulps (tests/test_trig.py bounds it against float64 numpy), the same order as XLA's.
A float32 call on fewer than :data:`SMALL` elements, counted over the whole batch under ``vmap``, uses XLA's own
function: on one or a few two-vehicle environments the polynomials' extra kernels cost more than they save.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.materialize import materialize

__all__ = ["sin", "cos", "sin_cos", "tan", "arctan", "arctan2", "arcsin"]

# pi/2 in three float32 parts (the first two with trailing zero bits, so k * part is exact for |k| < 2**12)
_PIO2_1 = np.float32(1.5703125)
_PIO2_2 = np.float32(4.837512969970703125e-4)
_PIO2_3 = np.float32(7.54978995489188216e-8)
_TWO_OVER_PI = np.float32(2 / np.pi)
# pi/4, pi/2 and pi as float32 plus the float32 nearest to what that float32 misses
_PIO4, _PIO4_LO = np.float32(np.pi / 4), np.float32(np.pi / 4 - float(np.float32(np.pi / 4)))
_PIO2, _PIO2_LO = np.float32(np.pi / 2), np.float32(np.pi / 2 - float(np.float32(np.pi / 2)))
_PI, _PI_LO = np.float32(np.pi), np.float32(np.pi - float(np.float32(np.pi)))
_TAN_PIO8 = np.float32(0.4142135623730950)


def _exact(x) -> bool:
    """XLA's own functions for float64 (and anything that is not float32)."""
    return jnp.result_type(x) != jnp.float32


def _poly(z, coefficients):
    """Horner's rule, highest degree first."""
    out = jnp.full_like(z, coefficients[0])
    for c in coefficients[1:]:
        out = out * z + c
    return out


def _reduce(x):
    """``x = k pi/2 + r`` with ``|r| <= pi/4`` (about): ``(r, k mod 4)``."""
    k = jnp.round(x * _TWO_OVER_PI)
    r = ((x - k * _PIO2_1) - k * _PIO2_2) - k * _PIO2_3
    return r, k.astype(jnp.int32) & 3


def _sin_poly(r, z):
    return r + r * z * _poly(z, (-1.9515295891e-4, 8.3321608736e-3, -1.6666654611e-1))


def _cos_poly(z):
    return 1 - 0.5 * z + z * z * _poly(z, (2.443315711809948e-5, -1.388731625493765e-3, 4.166664568298827e-2))


def _sin_cos_poly(x):
    """``(sin x, cos x)`` from one reduction."""
    r, q = _reduce(x)
    z = r * r
    s, c = _sin_poly(r, z), _cos_poly(z)
    swap = (q & 1) == 1
    sin_x = jnp.where(swap, c, s)
    cos_x = jnp.where(swap, s, c)
    sin_x = jnp.where(q >= 2, -sin_x, sin_x)
    cos_x = jnp.where((q == 1) | (q == 2), -cos_x, cos_x)
    return materialize((jnp.where(x == 0, x, sin_x), cos_x))  # sin(-0) = -0


def _tan_poly(x):
    r, q = _reduce(x)
    z = r * r
    t = r + r * z * _poly(z, (9.38540185543e-3, 3.11992232697e-3, 2.44301354525e-2, 5.34112807005e-2,
                              1.33387994085e-1, 3.33331568548e-1))
    return materialize(jnp.where(x == 0, x, jnp.where((q & 1) == 1, -1 / t, t)))  # tan(-0) = -0


def _atan_ratio(n, d):
    """``arctan(n / d)`` for ``0 <= n <= d`` (``d > 0``), one division either side of tan(pi/8)."""
    big = n > _TAN_PIO8 * d
    u = jnp.where(big, (n - d) / (n + d), n / d)
    z = u * u
    a = u + u * z * _poly(z, (8.05374449538e-2, -1.38776856032e-1, 1.99777106478e-1, -3.33329491539e-1))
    return jnp.where(big, _PIO4 + (a + _PIO4_LO), a)


def _arctan_poly(x):
    a = jnp.abs(x)
    inverted = a > 1
    r = _atan_ratio(jnp.where(inverted, 1, a), jnp.where(inverted, a, 1))
    r = jnp.where(inverted, _PIO2 - (r - _PIO2_LO), r)
    return materialize(jnp.where(x < 0, -r, r))  # keeps NaN, and the sign of zero


def _arctan2_poly(y, x):
    """The angle of ``(x, y)`` in ``[-pi, pi]`` (both zero: 0 or pi, as the sign of ``x``)."""
    ax, ay = jnp.abs(x), jnp.abs(y)
    lo, hi = jnp.minimum(ax, ay), jnp.maximum(ax, ay)
    r = _atan_ratio(lo, jnp.where(hi == 0, 1, hi))  # both zero: 0; NaN stays NaN
    r = jnp.where(ay > ax, _PIO2 - (r - _PIO2_LO), r)
    r = jnp.where(jnp.signbit(x), _PI - (r - _PI_LO), r)
    return materialize(jnp.where(jnp.signbit(y), -r, r))


def _arcsin_poly(x):
    """``arcsin x`` for ``-1 <= x <= 1``."""
    a = jnp.abs(x)
    high = a > 0.5
    z = jnp.where(high, 0.5 * (1 - a), a * a)
    s = jnp.where(high, jnp.sqrt(z), a)
    y = s + s * z * _poly(z, (4.2163199048e-2, 2.4181311049e-2, 4.5470025998e-2, 7.4953002686e-2, 1.6666752422e-1))
    y = jnp.where(high, _PIO2 - (2 * y - _PIO2_LO), y)
    return materialize(jnp.where(x < 0, -y, y))


# Below this many elements (counting the whole batch under ``vmap``) a float32 call uses XLA's own function:
# one fused operation, where a polynomial adds kernels and a buffer whose fixed cost outweighs its per-element
# gain on a few vehicles (one unbatched two-vehicle environment ran at half speed; docs/performance.md).
SMALL = 32


def _by_size(poly, xla):
    """``poly`` on float32 arrays of at least :data:`SMALL` elements, ``xla`` on smaller ones. Under ``vmap`` the
    choice is made on the batched shape (a custom batching rule that calls the function again on the whole
    batch), where the function body alone would only see one environment's few vehicles."""

    def unbatched(*xs):  # the arguments share one shape (``call`` broadcasts them)
        return poly(*xs) if xs[0].size >= SMALL else xla(*xs)

    f = jax.custom_batching.custom_vmap(unbatched)

    @f.def_vmap
    def rule(axis_size, in_batched, *xs):
        xs = [x if b else jnp.broadcast_to(x, (axis_size,) + x.shape) for x, b in zip(xs, in_batched)]
        out = f(*xs)
        return out, jax.tree_util.tree_map(lambda _: True, out)

    def call(*xs):
        return f(*jnp.broadcast_arrays(*[jnp.asarray(x, jnp.float32) for x in xs]))

    return call


_sin_cos = _by_size(_sin_cos_poly, lambda x: (jnp.sin(x), jnp.cos(x)))
_tan = _by_size(_tan_poly, jnp.tan)
_arctan = _by_size(_arctan_poly, jnp.arctan)
_arctan2 = _by_size(_arctan2_poly, jnp.arctan2)
_arcsin = _by_size(_arcsin_poly, jnp.arcsin)


def sin_cos(x):
    """``(sin x, cos x)`` (float32: from one reduction)."""
    return (jnp.sin(x), jnp.cos(x)) if _exact(x) else _sin_cos(x)


def sin(x):
    return jnp.sin(x) if _exact(x) else _sin_cos(x)[0]


def cos(x):
    return jnp.cos(x) if _exact(x) else _sin_cos(x)[1]


def tan(x):
    return jnp.tan(x) if _exact(x) else _tan(x)


def arctan(x):
    return jnp.arctan(x) if _exact(x) else _arctan(x)


def arctan2(y, x):
    """``arctan2(y, x)``: the angle of ``(x, y)`` in ``[-pi, pi]`` (both zero: 0 or pi, as the sign of ``x``)."""
    return jnp.arctan2(y, x) if _exact(y) and _exact(x) else _arctan2(y, x)


def arcsin(x):
    """``arcsin x`` for ``-1 <= x <= 1``."""
    return jnp.arcsin(x) if _exact(x) else _arcsin(x)
