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

import jax.numpy as jnp
import numpy as np

from envs_jax import collision
from envs_jax import vehicle as Veh
from envs_jax.materialize import materialize
from envs_jax.sparse import TableRows, sparse_map

# Separating-axis rows packed per vehicle slot and env under vmap (more run in extra chunks).
SAT_ROWS_PER_VEHICLE = 0.08


def pair_table(n_slots: int, n_obstacles: int, check_collisions):
    """Static ``[V, V + O]`` flags of the pairs highway-env checks: row ``i`` against column ``j > i``
    (vehicle slots, then obstacles ``V + o``), where either side has ``check_collisions``
    (obstacles always do). Row-major order over the table is the loop order."""
    check = np.concatenate([np.asarray(check_collisions, bool), np.ones(n_obstacles, bool)])
    upper = np.arange(n_slots + n_obstacles)[None, :] > np.arange(n_slots)[:, None]
    return upper & (check[:n_slots, None] | check[None, :])


def collide(x, y, heading, speed, alive, crashed, check_collisions, obstacles, dt):
    """Impacts ``[V, 2]``, their flags and the updated ``crashed`` after one frame's checks.

    ``check_collisions``: static ``[V]`` flags; ``obstacles``: ``[O, 5]`` rows
    ``x, y, heading, length, width`` or None. The prefilter runs over a dense ``[V, V + O]`` pair table
    (broadcasts); the separating-axis test and the per-vehicle results only for the close pairs.
    """
    n_slots = x.shape[0]
    dtype = x.dtype
    n_obs = 0 if obstacles is None else int(obstacles.shape[0])
    n_obj = n_slots + n_obs
    checked = pair_table(n_slots, n_obs, check_collisions)
    if not checked.any():
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
    active = present[:n_slots, None] & present[None, :] & jnp.asarray(checked)  # [V, V + O]

    # the bounding-circle prefilter for every pair at once (rows: the first object of the pair)
    diagonal = jnp.sqrt(pl ** 2 + pw ** 2)
    ends = lambda sel: collision.Shape(sel(px), sel(py), sel(pv), sel(diagonal), None, None, None)
    close = collision.near(ends(lambda a: a[:n_slots, None]), ends(lambda a: a[None, :]), dt) & active
    close = materialize(close)  # once, in this layout: sparse_map's packing reads it in another order

    def separating_axis(pa, pb, key):
        sa, sb = collision.Shape.make(*pa), collision.Shape.make(*pb)
        disp_a = jnp.stack([sa.vx, sa.vy]) * dt
        disp_b = jnp.stack([sb.vx, sb.vy]) * dt
        inter, will, trans = collision.polygons_intersecting(sa.corners, sb.corners, disp_a, disp_b)
        # for both vehicles of the pair: crashed, and this pair's loop position + 1 where it gives an impact
        crash = inter.astype(jnp.int32)
        last = jnp.where(will, key + 1, 0)
        return trans, (jnp.stack([crash, crash]), jnp.stack([last, last]))

    # chunks sized by the vehicles, not the pairs: each vehicle has a few close neighbours, not O(V)
    n_rows = n_slots * n_obj
    fraction = min(1 / 32, SAT_ROWS_PER_VEHICLE * n_slots / n_rows)
    flat = np.arange(n_rows, dtype=np.int32)  # a pair's position in the loop
    first, second = flat // n_obj, flat % n_obj
    # per-vehicle maxima, scattered from the close pairs only: segment v (as the pair's first object) and
    # V + v (as its second; obstacles have none)
    segments = np.stack([first, np.where(second < n_slots, n_slots + second, -1)], axis=-1)
    # poses gathered only for the packed close pairs
    rows_a, rows_b = TableRows(pose, jnp.asarray(first)), TableRows(pose, jnp.asarray(second))
    trans, (crash, last) = sparse_map(separating_axis, close.reshape(n_rows), rows_a, rows_b, jnp.asarray(flat),
                                      fraction=fraction, segments=segments, n_segments=2 * n_slots)
    crashed = crashed | (crash[:n_slots] > 0) | (crash[n_slots:] > 0)
    # a vehicle's impact is that of the last pair (loop order) involving it
    last_a, last_b = last[:n_slots] - 1, last[n_slots:] - 1  # as the first object of the pair, as the second
    from_a = last_a >= last_b
    last = jnp.maximum(last_a, last_b)
    c = jnp.maximum(last, 0)
    value_a = jnp.where((c % n_obj < n_slots)[:, None], trans[c] / 2, trans[c])
    impact = jnp.where(from_a[:, None], value_a, -trans[c] / 2)
    has_impact = last >= 0
    impact = jnp.where(has_impact[:, None], impact, 0.0)
    return impact.astype(dtype), has_impact, crashed
