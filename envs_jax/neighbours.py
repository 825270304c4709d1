"""``Road.neighbour_vehicles``: the nearest object ahead and behind a vehicle on a given lane.

highway-env projects the vehicle and every other road object (vehicles in list
order, then obstacles) on the lane, keeps the objects that are on it with a 1 m
lateral margin (``lane.on_lane(..., margin=1)``) and takes the nearest
longitudinal coordinate ahead (``s <= s_v``; on ties the *last* object in list
order wins) and behind (``s_v < s``; on ties the *first* wins). Objects are
indexed here in that list order: vehicle slots first, then obstacles.
"""

from __future__ import annotations

import jax.numpy as jnp

from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from envs_jax.materialize import materialize

MARGIN = 1.0  # lateral margin of the on-lane test [m]


def coordinates_on(lanes: L.LaneTable, query_lane, px, py, circles=None):
    """``lane.local_coordinates`` of every object ``(px, py)`` (``[N]``) on the lanes ``query_lane``
    (any shape ``[...]``): ``(s, lat)`` of shape ``[..., N]``. ``circles``: the objects'
    :func:`~envs_jax.lane_locate.circle_coords`, if already computed."""
    q = jnp.asarray(query_lane)[..., None]
    shape = q.shape[:-1] + px.shape
    if circles is None:
        circles = LL.circle_coords(lanes, px, py)  # [N, C]: once per object, not per query lane
    # lane rows gathered per query lane ([..., 1]) and broadcast over the objects; only the
    # lane families the road has (a straight road costs no trigonometry)
    # with fewer sine lanes than query lanes, a sine lane's offset once per object and sine lane
    # rather than once per object and query lane (the same values)
    per_object = 0 < lanes.sine_rows.size < q.size
    s, lat = LL.lane_coords(lanes, px, py, circles, q, sine=not per_object)
    if per_object:
        offset, on_sine = LL.sine_offsets(lanes, px, py, q)
        lat = jnp.where(on_sine, lat - offset, lat)
    return jnp.broadcast_to(s, shape), jnp.broadcast_to(lat, shape)


def on_lane(lanes: L.LaneTable, query_lane, s, lat):
    """``lane.on_lane(position, s, lat, margin=1)`` for coordinates ``[..., N]`` on ``query_lane`` ``[...]``."""
    q = jnp.asarray(query_lane)[..., None]
    width = lanes.col("width")[q]
    length = lanes.col("length")[q]
    return (jnp.abs(lat) <= width / 2 + MARGIN) & (-L.VEHICLE_LENGTH <= s) & (s < length + L.VEHICLE_LENGTH)


def front_rear(s_ego, s, on):
    """Indices of the preceding and following objects (``-1``: none) from the ego's coordinate
    ``s_ego`` ``[...]`` and the objects' coordinates ``s`` and eligibility ``on`` ``[..., N]``
    (``on`` must already exclude the ego itself and empty slots).

    One pass over the objects in list order keeps the best so far, elementwise over ``[...]``:
    XLA fuses the unrolled chain into one loop, where reductions along the short object axis
    would each run as a separate, poorly vectorised loop. A later object at the same ``s``
    replaces the front (the last one wins) but not the rear (the first one wins). The
    eligibility is folded into the coordinates once (NaN where not eligible: every comparison
    with it is false), so each step of the pass reads one array and evaluates no on-lane test.
    """
    s_ego = jnp.asarray(s_ego)
    s = materialize(jnp.where(on, s, jnp.nan))
    best_front = jnp.full(s_ego.shape, jnp.inf, s.dtype)
    best_rear = jnp.full(s_ego.shape, -jnp.inf, s.dtype)
    front = jnp.full(s_ego.shape, -1, jnp.int32)
    rear = jnp.full(s_ego.shape, -1, jnp.int32)
    for j in range(s.shape[-1]):
        s_j = s[..., j]
        ahead = (s_ego <= s_j) & (s_j <= best_front)
        behind = (s_j < s_ego) & ((s_j > best_rear) | (rear < 0))
        best_front, front = jnp.where(ahead, s_j, best_front), jnp.where(ahead, j, front)
        best_rear, rear = jnp.where(behind, s_j, best_rear), jnp.where(behind, j, rear)
    return front, rear


def neighbour_vehicles(lanes: L.LaneTable, ego, query_lane, px, py, valid):
    """``road.neighbour_vehicles(objects[ego], query_lane)`` for one or many egos.

    ``px, py, valid``: ``[N]`` positions and presence of all objects (list order);
    ``ego`` and ``query_lane`` broadcast together. Returns ``(front, rear)`` indices.
    """
    s, lat = coordinates_on(lanes, query_lane, px, py)
    ego = jnp.asarray(ego)
    s_ego = jnp.take_along_axis(s, jnp.broadcast_to(ego, s.shape[:-1])[..., None], axis=-1)[..., 0]
    eligible = on_lane(lanes, query_lane, s, lat) & valid & (jnp.arange(px.shape[-1]) != ego[..., None])
    return front_rear(s_ego, s, eligible)
