"""``Road.step``'s collision loop for V vehicle slots and O obstacles, in list order.

highway-env checks ``vehicles[i].handle_collisions(vehicles[j])`` for ``i < j``, then
``vehicles[i]`` against every obstacle, for ``i`` in list order. A pair is checked
when either side has ``check_collisions`` (obstacles always do). ``intersecting``
latches ``crashed`` on both; ``will_intersect`` *overwrites* both impacts
(``t / 2`` and ``-t / 2``; a vehicle against an obstacle takes the whole ``t``), so a
vehicle's impact is the one of the last pair involving it, in loop order. Each
check is :func:`collision.near` (bounding circles, widened by the first object's
travel) and, for the pairs that pass it, the separating-axis test (``sparse_map``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import collision
from envs_jax import vehicle as Veh
from envs_jax.sparse import TableRows, sparse_map

# Separating-axis rows packed per vehicle slot and env under vmap (more run in extra chunks).
SAT_ROWS_PER_VEHICLE = 0.25


def pair_table(n_slots: int, n_obstacles: int, check_collisions):
    """Static ``(a, b, checked)`` arrays of the pairs in loop order (obstacles are ``V + o``)."""
    check = np.asarray(check_collisions, bool)
    a, b = [], []
    for i in range(n_slots):
        for j in range(i + 1, n_slots):
            a.append(i)
            b.append(j)
        for o in range(n_obstacles):
            a.append(i)
            b.append(n_slots + o)
    a = np.asarray(a, np.int32)
    b = np.asarray(b, np.int32)
    checked = check[a] | np.where(b < n_slots, check[np.minimum(b, n_slots - 1)], True)
    return a, b, checked


def collide(x, y, heading, speed, alive, crashed, check_collisions, obstacles, dt):
    """Impacts ``[V, 2]``, their flags and the updated ``crashed`` after one frame's checks.

    ``check_collisions``: static ``[V]`` flags; ``obstacles``: ``[O, 5]`` rows
    ``x, y, heading, length, width`` or None.
    """
    n_slots = x.shape[0]
    dtype = x.dtype
    n_obs = 0 if obstacles is None else int(obstacles.shape[0])
    a, b, checked = pair_table(n_slots, n_obs, check_collisions)
    if a.size == 0:
        return jnp.zeros((n_slots, 2), dtype), jnp.zeros(n_slots, bool), crashed
    length = jnp.full(n_slots, Veh.LENGTH, dtype)
    width = jnp.full(n_slots, Veh.WIDTH, dtype)
    px, py, ph, pv, pl, pw, present = x, y, heading, speed, length, width, alive
    if n_obs:
        ob = jnp.asarray(obstacles, dtype)
        cat = lambda u, w: jnp.concatenate([u, w])
        px, py, ph = cat(px, ob[:, 0]), cat(py, ob[:, 1]), cat(ph, ob[:, 2])
        pv, pl, pw = cat(pv, jnp.zeros(n_obs, dtype)), cat(pl, ob[:, 3]), cat(pw, ob[:, 4])
        present = cat(present, jnp.ones(n_obs, bool))
    pose = jnp.stack([px, py, ph, pv, pl, pw], axis=-1)
    pose_a, pose_b = pose[a], pose[b]
    active = present[a] & present[b] & jnp.asarray(checked)

    def near(pa, pb):
        return collision.near(collision.Shape.make(*pa), collision.Shape.make(*pb), dt)

    def separating_axis(pa, pb):
        sa, sb = collision.Shape.make(*pa), collision.Shape.make(*pb)
        disp_a = jnp.stack([sa.vx, sa.vy]) * dt
        disp_b = jnp.stack([sb.vx, sb.vy]) * dt
        return collision.polygons_intersecting(sa.corners, sb.corners, disp_a, disp_b)

    close = jax.vmap(near)(pose_a, pose_b) & active
    # chunks sized by the vehicles, not the pairs: each vehicle has a few close neighbours, not O(V)
    fraction = min(1 / 32, SAT_ROWS_PER_VEHICLE * n_slots / a.size)
    # the poses are gathered again only for the packed close pairs (pose_a/pose_b are fused into `near`)
    rows_a, rows_b = TableRows(pose, jnp.asarray(a)), TableRows(pose, jnp.asarray(b))
    inter, will, trans = sparse_map(separating_axis, close, rows_a, rows_b, fraction=fraction)
    inter, will = inter & close, will & close

    b_vehicle = b < n_slots
    b_slot = np.minimum(b, n_slots - 1)
    hit = jnp.zeros(n_slots, bool).at[a].max(inter).at[b_slot].max(inter & b_vehicle)
    crashed = crashed | hit
    order = jnp.arange(a.size, dtype=jnp.int32)
    key = jnp.where(will, order, -1)
    last_a = jnp.full(n_slots, -1, jnp.int32).at[a].max(key)
    last_b = jnp.full(n_slots, -1, jnp.int32).at[b_slot].max(jnp.where(b_vehicle, key, -1))
    from_a = last_a >= last_b
    last = jnp.maximum(last_a, last_b)
    c = jnp.maximum(last, 0)
    value_a = jnp.where(jnp.asarray(b_vehicle)[c][:, None], trans[c] / 2, trans[c])
    impact = jnp.where(from_a[:, None], value_a, -trans[c] / 2)
    has_impact = last >= 0
    impact = jnp.where(has_impact[:, None], impact, 0.0)
    return impact.astype(dtype), has_impact, crashed
