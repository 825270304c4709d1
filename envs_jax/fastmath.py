"""Trigonometric functions that are fast in float32 on CPU and exact-as-libm in float64.

XLA lowers ``sin``, ``cos``, ``tan``, ``atan2`` (and ``arctan`` / ``arcsin``
through it) to scalar library calls on CPU: 10-25 ns per element against
0.5 ns for arithmetic, which made them most of the simulator's cost. In
float32 these functions are evaluated with the classic Cephes single-precision
polynomials (range reduction + minimax polynomial, within a few float32 ulp
over the ranges the simulator uses), written as plain arithmetic that XLA
vectorises. In float64 they are ``jnp``'s own, so x64 parity checks against
highway-env use the same functions as numpy up to libm's last ulp.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

_PI = np.pi
_PIO2 = np.pi / 2
_PIO4 = np.pi / 4
_FOPI = 4 / np.pi
# Cody-Waite split of pi/4 (Cephes sinf.c): DP1 + DP2 + DP3 = pi/4 to ~1e-15.
_DP1, _DP2, _DP3 = 0.78515625, 2.4187564849853515625e-4, 3.77489497744594108e-8
_TAN3PIO8 = 2.414213562373095
_TANPIO8 = 0.4142135623730950


def _is64(x) -> bool:
    return jnp.asarray(x).dtype == jnp.float64


def _reduce(x):
    """|x| = j pi/4 + z with j even and |z| <= pi/4; returns (z, j mod 8)."""
    ax = jnp.abs(x)
    j = jnp.floor(ax * _FOPI)
    j = j + (j - 2 * jnp.floor(j / 2))  # round up to an even multiple (j >= 0; floor, not slow fmod)
    z = ((ax - j * _DP1) - j * _DP2) - j * _DP3
    return z, (j - 8 * jnp.floor(j / 8)).astype(jnp.int32)


def _sin_poly(z, zz):
    return ((-1.9515295891e-4 * zz + 8.3321608736e-3) * zz - 1.6666654611e-1) * zz * z + z


def _cos_poly(zz):
    return ((2.443315711809948e-5 * zz - 1.388731625493765e-3) * zz + 4.166664568298827e-2) * zz * zz - 0.5 * zz + 1.0


def sincos(x):
    """``(sin x, cos x)`` sharing one range reduction."""
    x = jnp.asarray(x)
    if _is64(x):
        return jnp.sin(x), jnp.cos(x)
    z, j = _reduce(x)
    zz = z * z
    ps, pc = _sin_poly(z, zz), _cos_poly(zz)
    swap = (j == 2) | (j == 6)
    s = jnp.where(swap, pc, ps)
    c = jnp.where(swap, ps, pc)
    s = jnp.where(j >= 4, -s, s)
    s = jnp.where(x < 0, -s, s)
    c = jnp.where((j == 2) | (j == 4), -c, c)
    return s, c


def sin(x):
    return jnp.sin(x) if _is64(x) else sincos(x)[0]


def cos(x):
    return jnp.cos(x) if _is64(x) else sincos(x)[1]


def tan(x):
    if _is64(x):
        return jnp.tan(x)
    s, c = sincos(x)
    return s / c


def arctan(x):
    """Cephes ``atanf``: reduction by tan(3 pi/8) and tan(pi/8), then a degree-9 odd polynomial."""
    x = jnp.asarray(x)
    if _is64(x):
        return jnp.arctan(x)
    ax = jnp.abs(x)
    big = ax > _TAN3PIO8
    mid = (ax > _TANPIO8) & ~big
    safe = jnp.where(big, ax, 1.0)
    t = jnp.where(big, -1.0 / safe, jnp.where(mid, (ax - 1.0) / (ax + 1.0), ax))
    base = jnp.where(big, _PIO2, jnp.where(mid, _PIO4, 0.0))
    z = t * t
    y = base + ((((8.05374449538e-2 * z - 1.38776856032e-1) * z + 1.99777106478e-1) * z
                 - 3.33329491539e-1) * z * t + t)
    return jnp.where(x < 0, -y, y)


def arctan2(y, x):
    """Quadrant-correct ``atan2`` built on :func:`arctan`."""
    y = jnp.asarray(y)
    x = jnp.asarray(x)
    if _is64(y) or _is64(x):
        return jnp.arctan2(y, x)
    ay, ax = jnp.abs(y), jnp.abs(x)
    # atan(min/max) stays in [0, pi/4]: accurate and free of overflow.
    swap = ay > ax
    num = jnp.where(swap, ax, ay)
    den = jnp.where(swap, ay, ax)
    r = arctan(num / jnp.where(den == 0, 1.0, den))
    r = jnp.where(swap, _PIO2 - r, r)
    r = jnp.where(x < 0, _PI - r, r)
    return jnp.where(y < 0, -r, r)


def arcsin(x):
    """Cephes ``asinf``: polynomial on [0, 0.5], half-angle identity above."""
    x = jnp.asarray(x)
    if _is64(x):
        return jnp.arcsin(x)
    a = jnp.abs(x)
    upper = a > 0.5
    z = jnp.where(upper, 0.5 * (1.0 - a), a * a)
    t = jnp.where(upper, jnp.sqrt(z), a)
    p = ((((4.2163199048e-2 * z + 2.4181311049e-2) * z + 4.5470025998e-2) * z + 7.4953002686e-2) * z
         + 1.6666752422e-1) * z * t + t
    p = jnp.where(upper, _PIO2 - 2.0 * p, p)
    return jnp.where(x < 0, -p, p)
