"""Collisions between rotated rectangles (highway-env ``RoadObject.handle_collisions``).

A bounding-circle prefilter, then the separating-axis test of
``utils.are_polygons_intersecting`` over the 4 edge normals of each rectangle,
with the relative displacement over one step swept into the first rectangle's
projection. It returns whether the rectangles intersect now, whether they will
intersect after the step, and the minimum translation vector that pushes the
first rectangle out of the second.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from envs_jax import trig


def rectangle(x, y, heading, length, width, c=None, s=None):
    """The 4 corners ``[4, 2]`` of ``RoadObject.polygon()`` (same order, same arithmetic).

    ``c, s`` may pass a precomputed ``cos(heading), sin(heading)``.
    """
    hl, hw = length / 2, width / 2
    local = jnp.array([[-1.0, -1.0], [-1.0, 1.0], [1.0, 1.0], [1.0, -1.0]])
    px = local[:, 0] * hl
    py = local[:, 1] * hw
    if c is None:
        s, c = trig.sin_cos(heading)
    cx = c * px + (-s) * py + x
    cy = s * px + c * py + y
    return jnp.stack([cx, cy], axis=-1)


def _interval_distance(min_a, max_a, min_b, max_b):
    return jnp.where(min_a < min_b, min_b - max_a, min_a - max_b)


def polygons_intersecting(a, b, disp_a, disp_b):
    """``are_polygons_intersecting(a, b, disp_a, disp_b)`` for two quadrilaterals ``[4, 2]``.

    Returns ``(intersecting, will_intersect, translation[2])``; translation is
    zero unless ``will_intersect``. The axis of minimum |overlap| is the first
    one reaching it, in the order edges of ``a`` then edges of ``b``.
    """
    edges = []
    for poly in (a, b):
        p1 = poly
        p2 = jnp.roll(poly, -1, axis=0)
        edges.append((p1, p2))
    p1 = jnp.concatenate([edges[0][0], edges[1][0]], axis=0)  # [8, 2]
    p2 = jnp.concatenate([edges[0][1], edges[1][1]], axis=0)
    nx = -p2[:, 1] + p1[:, 1]
    ny = p2[:, 0] - p1[:, 0]
    norm = jnp.sqrt(nx * nx + ny * ny)
    nx, ny = nx / norm, ny / norm  # [8]
    proj_a = a[None, :, 0] * nx[:, None] + a[None, :, 1] * ny[:, None]  # [8, 4]
    proj_b = b[None, :, 0] * nx[:, None] + b[None, :, 1] * ny[:, None]
    min_a, max_a = proj_a.min(axis=1), proj_a.max(axis=1)
    min_b, max_b = proj_b.min(axis=1), proj_b.max(axis=1)
    separated_now = _interval_distance(min_a, max_a, min_b, max_b) > 0
    intersecting = ~jnp.any(separated_now)
    dvx = disp_a[0] - disp_b[0]
    dvy = disp_a[1] - disp_b[1]
    vproj = nx * dvx + ny * dvy
    min_a = jnp.where(vproj < 0, min_a + vproj, min_a)
    max_a = jnp.where(vproj < 0, max_a, max_a + vproj)
    dist = _interval_distance(min_a, max_a, min_b, max_b)
    will_intersect = ~jnp.any(dist > 0)
    k = jnp.argmin(jnp.abs(dist))
    cdx = a[:, 0].mean() - b[:, 0].mean()
    cdy = a[:, 1].mean() - b[:, 1].mean()
    sign = jnp.where(cdx * nx[k] + cdy * ny[k] > 0, 1.0, -1.0)
    min_dist = jnp.abs(dist[k])
    tx = jnp.where(will_intersect, min_dist * sign * nx[k], 0.0)
    ty = jnp.where(will_intersect, min_dist * sign * ny[k], 0.0)
    return intersecting, will_intersect, jnp.stack([tx, ty])


class Shape(NamedTuple):
    """A rectangle ready for collision checks: centre, speed, corners and velocity."""

    x: jax.Array
    y: jax.Array
    speed: jax.Array
    diagonal: jax.Array
    corners: jax.Array  # [4, 2]
    vx: jax.Array  # velocity (speed * direction, no slip angle)
    vy: jax.Array

    @staticmethod
    def make(x, y, heading, speed, length, width):
        s, c = trig.sin_cos(heading)
        return Shape(x, y, speed, jnp.sqrt(length ** 2 + width ** 2),
                     rectangle(x, y, heading, length, width, c, s), speed * c, speed * s)


def near(a: Shape, b: Shape, dt):
    """The prefilter of ``a._is_colliding(b, dt)``: centres closer than the half diagonals plus
    ``a``'s travel over the step (only ``a``'s speed counts, as in highway-env)."""
    dx, dy = b.x - a.x, b.y - a.y
    return ~(jnp.sqrt(dx * dx + dy * dy) > (a.diagonal + b.diagonal) / 2 + a.speed * dt)


def check(a: Shape, b: Shape, dt):
    """``a._is_colliding(b, dt)``: prefilter on centre distance, then the separating-axis test.

    ``a`` is the object calling ``handle_collisions``: its speed widens the prefilter.
    Returns ``(intersecting, will_intersect, translation[2])``.
    """
    far = ~near(a, b, dt)
    disp_a = jnp.stack([a.vx, a.vy]) * dt
    disp_b = jnp.stack([b.vx, b.vy]) * dt
    inter, will, trans = polygons_intersecting(a.corners, b.corners, disp_a, disp_b)
    return inter & ~far, will & ~far, jnp.where(far, 0.0, trans)
