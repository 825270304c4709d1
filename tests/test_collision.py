"""Rotated-rectangle collisions against hand-built cases and highway-env's separating-axis test."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from highway_env import utils as hutils

from envs_jax import collision as C


def _shape(x, y, h, v, length=5.0, width=2.0):
    return C.Shape.make(jnp.asarray(x), jnp.asarray(y), jnp.asarray(h), jnp.asarray(v), length, width)


@pytest.mark.parametrize("dx,dy,h,expect", [
    (4.9, 0.0, 0.0, True),  # nose to tail, 0.1 m overlap
    (5.1, 0.0, 0.0, False),  # 0.1 m apart
    (0.0, 1.9, 0.0, True),  # side by side, overlapping
    (0.0, 2.1, 0.0, False),
    (4.2, 3.0, np.pi / 4, False),  # rotated neighbour: its near edge is x + y = 3.66 > 3.5 (A's corner)
    (3.0, 3.0, np.pi / 4, True),  # its near corner (1.94, 0.52) lies inside A
    (2.0, 1.0, np.pi / 2, True),  # crossing at right angles
])
def test_hand_built_rectangles(dx, dy, h, expect):
    inter, will, _ = C.check(_shape(0, 0, 0, 0), _shape(dx, dy, h, 0), 1 / 15)
    assert bool(inter) == expect and bool(will) == expect


def test_will_intersect_from_relative_motion():
    """0.5 m apart, closing at 10 m/s over 1/15 s (0.67 m): not yet intersecting, will intersect."""
    inter, will, t = C.check(_shape(0, 0, 0, 10.0), _shape(5.5, 0, 0, 0.0), 1 / 15)
    assert not bool(inter) and bool(will)
    assert float(t[0]) < 0  # pushes the first car back


def test_prefilter_uses_first_objects_speed():
    """The bounding-circle test adds only the first object's speed * dt (highway-env's quirk)."""
    a, b = _shape(0, 0, 0, 0.0), _shape(5.5, 0, 0, -30.0)  # b closes at 30 m/s, a is still
    _, will_ab, _ = C.check(a, b, 1 / 15)
    assert not bool(will_ab)  # distance 5.5 > diag + 0: filtered before the SAT sweep


def test_matches_highway_env_on_random_pairs(x64):
    rng = np.random.default_rng(0)
    n = 3000
    xa, ya = rng.uniform(-6, 6, n), rng.uniform(-4, 4, n)
    ha, hb = rng.uniform(-np.pi, np.pi, n), rng.uniform(-np.pi, np.pi, n)
    va, vb = rng.uniform(-15, 15, n), rng.uniform(-15, 15, n)
    dt = 1 / 15
    out = jax.vmap(lambda *a: C.polygons_intersecting(
        C.rectangle(a[0], a[1], a[2], 5.0, 2.0), C.rectangle(0.0, 0.0, a[3], 5.0, 2.0),
        jnp.stack([a[4] * jnp.cos(a[2]), a[4] * jnp.sin(a[2])]) * dt,
        jnp.stack([a[5] * jnp.cos(a[3]), a[5] * jnp.sin(a[3])]) * dt))(
        *(jnp.asarray(v) for v in (xa, ya, ha, hb, va, vb)))
    inter, will, trans = (np.asarray(o) for o in out)
    tx, ty = trans[:, 0], trans[:, 1]

    def poly(x, y, h):
        pts = np.array([[-2.5, -1], [-2.5, 1], [2.5, 1], [2.5, -1]]).T
        c, s = np.cos(h), np.sin(h)
        pts = (np.array([[c, -s], [s, c]]) @ pts).T + np.tile([x, y], (4, 1))
        return np.vstack([pts, pts[0:1]])

    for i in range(n):
        e_inter, e_will, e_t = hutils.are_polygons_intersecting(
            poly(xa[i], ya[i], ha[i]), poly(0, 0, hb[i]),
            va[i] * np.array([np.cos(ha[i]), np.sin(ha[i])]) * dt,
            vb[i] * np.array([np.cos(hb[i]), np.sin(hb[i])]) * dt)
        assert bool(inter[i]) == e_inter and bool(will[i]) == e_will
        if e_will:
            np.testing.assert_allclose([tx[i], ty[i]], e_t, atol=1e-9)
    assert 0.2 < inter.mean() < 0.9  # the sample exercises both outcomes
