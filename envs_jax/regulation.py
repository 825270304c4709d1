"""highway-env's ``RegulatedRoad`` (``road/regulation.py``): right of way at a junction, branch-free.

Every ``int(1 / dt / REGULATION_FREQUENCY)`` road steps (counted from the road's
creation, warm-up included), after ``road.act()`` and before the kinematics,
``enforce_road_rules``:

1. releases the yielding vehicles whose yield timer has run
   ``YIELD_DURATION * REGULATION_FREQUENCY`` checks (target speed back to their
   lane's speed limit), the others' timers count one more check;
2. for every pair of vehicles ``i < j`` whose constant-speed predictions along their
   routes (:func:`predict_along_route`) come within a rectangle overlap over the
   horizon (:func:`conflicts`), the vehicle that must give way
   (:func:`yielding_side`: lower lane priority, or on equal priority the one behind)
   stops (target speed 0) if it is an IDM driver (``ControlledVehicle`` but not
   ``MDPVehicle``).

The pair decisions only set flags, so the loop order matters only through which
vehicle of a pair is ``v1`` (the tie rule of :func:`yielding_side`); all pairs are
decided at once as a ``[V, V]`` matrix, under ``vmap`` the rectangle test run only on the
pairs that pass the bounding-circle pre-check (docs/scenarios.md, "intersection-v0 with traffic").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import lanes as L
from envs_jax import trig
from envs_jax import vehicle as Veh
from envs_jax.materialize import materialize
from envs_jax.road import Road
from envs_jax.sparse import TableRows, sparse_map
from envs_jax.traffic_state import TrafficState

REGULATION_FREQUENCY = 2  # [Hz] RegulatedRoad.REGULATION_FREQUENCY
YIELD_DURATION = 0.0  # [s] RegulatedRoad.YIELD_DURATION
HORIZON = 3  # [s] is_conflict_possible's horizon
STEP = 0.25  # [s] is_conflict_possible's step
PREDICTION_TIMES = np.arange(STEP, HORIZON, STEP)  # np.arange(step, horizon, step), as highway-env builds it
CONFLICT_LENGTH = 1.5 * Veh.LENGTH  # the predicted rectangles: 1.5 x length, 0.9 x width
CONFLICT_WIDTH = 0.9 * Veh.WIDTH
CONFLICT_ROWS_PER_VEHICLE = 0.2  # rectangle tests per vehicle slot and env (intersection-v0: 1.7 pairs of 24 slots)
DENSE_BATCH = 1  # batches up to this size test every pair (for one environment packing costs more than it saves)


def regulation_period(simulation_frequency: int) -> int:
    """Road steps between two ``enforce_road_rules`` calls: ``int(1 / dt / REGULATION_FREQUENCY)``."""
    dt = 1 / simulation_frequency
    return int(1 / dt / REGULATION_FREQUENCY)


def predict_along_route(road: Road, st: TrafficState, times):
    """``ControlledVehicle.predict_trajectory_constant_speed(times)`` for every slot: ``(x, y, heading)`` ``[V, T]``.

    The start is the longitudinal coordinate on the *current* lane plus ``speed * t``;
    it is walked along the remaining route (or the current lane when the route is
    empty), moving to the next entry while more than one entry remains and the
    coordinate exceeds the entry's lane length. Route entries without a lane id take
    the current lane's id.
    """
    lanes = road.lanes
    s0, _ = L.local_coordinates(lanes, st.lane, st.x, st.y)
    longitudinal = s0[:, None] + st.speed[:, None] * times[None, :]
    road_lanes = jnp.asarray(road.road_lanes)
    road_num = jnp.asarray(road.road_num_lanes)
    cur_id = jnp.asarray(road.lane_id)[st.lane]
    n_route = st.route_roads.shape[-1]
    has_route = st.route_ptr < st.route_len
    remaining = jnp.where(has_route, st.route_len - st.route_ptr, 1)

    slot = jnp.arange(st.x.shape[0])[:, None]

    def entry_lane(ptr):  # [V, T]
        k = jnp.clip(ptr, 0, n_route - 1)
        r = jnp.maximum(st.route_roads[slot, k], 0)
        i = st.route_ids[slot, k]
        i = jnp.where(i >= 0, i, cur_id[:, None])
        i = jnp.minimum(i, road_num[r] - 1)
        return jnp.where(has_route[:, None], road_lanes[r, i], st.lane[:, None])

    shape = longitudinal.shape
    ptr = jnp.broadcast_to(st.route_ptr[:, None], shape)
    remaining = jnp.broadcast_to(remaining[:, None], shape)
    lane = entry_lane(ptr)
    length = lanes.col("length")
    for _ in range(n_route - 1):
        more = (remaining > 1) & (longitudinal > length[lane])
        longitudinal = jnp.where(more, longitudinal - length[lane], longitudinal)
        ptr = ptr + more
        remaining = remaining - more
        lane = entry_lane(ptr)

    def at_time(lane_s):  # every slot's pose at one time of the horizon
        lane_t, s_t = lane_s
        x, y = L.position(lanes, lane_t, s_t, jnp.zeros_like(s_t))
        return x, y, L.heading_at(lanes, lane_t, s_t)

    # one time per loop iteration: a loop's outputs are materialised, so the [V, V, T] pair checks read them; as
    # one elementwise expression XLA fuses the lane geometry (its sines and cosines) into those checks and redoes
    # it for every pair
    x, y, heading = jax.lax.map(at_time, (lane.T, longitudinal.T))
    return x.T, y.T, heading.T


def _corners(x, y, c, s):
    """``rect_corners(center, 1.5 L, 0.9 W, heading, include_midpoints=True, include_center=True)``: ``[..., 9]``
    x and y, from the heading's cosine ``c`` and sine ``s``."""
    hl, hw = CONFLICT_LENGTH / 2, CONFLICT_WIDTH / 2
    local = np.array([[-hl, -hw], [-hl, hw], [hl, hw], [hl, -hw], [0, 0], [-hl, 0], [hl, 0], [0, -hw], [0, hw]])
    c, s = c[..., None], s[..., None]
    lx, ly = jnp.asarray(local[:, 0], x.dtype), jnp.asarray(local[:, 1], x.dtype)
    return c * lx - s * ly + x[..., None], s * lx + c * ly + y[..., None]


def _inside(px, py, x, y, c, s):
    """``point_in_rotated_rectangle(p, center, 1.5 L, 0.9 W, heading)`` (highway-env rotates ``p - center`` by
    ``+heading``: cosine ``c``, sine ``s``), inclusive bounds; ``p`` ``[..., 9]``, the rectangle ``[...]``."""
    c, s = c[..., None], s[..., None]
    dx, dy = px - x[..., None], py - y[..., None]
    u, v = c * dx - s * dy, s * dx + c * dy
    hl, hw = CONFLICT_LENGTH / 2, CONFLICT_WIDTH / 2
    return (-hl <= u) & (u <= hl) & (-hw <= v) & (v <= hw)


def conflicts(px, py, ph, alive=None):
    """``is_conflict_possible`` for every pair: ``[V, V]`` (symmetric, False on the diagonal) from predictions
    ``[V, T]``; ``alive`` (``[V]``, default all): pairs with an empty slot are False.

    For one environment (unbatched, or a batch of ``DENSE_BATCH``) every pair is tested at once
    (:func:`_conflicts_dense`); under ``vmap`` the bounding-circle pre-check runs for every pair and the rectangle
    test only for the pairs that pass it at some time (:func:`_conflicts_sparse`): about two pairs of an
    intersection's hundreds. Both give the same answer."""
    if alive is None:
        alive = jnp.ones(px.shape[0], bool)
    f = jax.custom_batching.custom_vmap(_conflicts_dense)

    @f.def_vmap
    def rule(axis_size, in_batched, *args):
        args = [a if b else jnp.broadcast_to(a, (axis_size,) + a.shape) for a, b in zip(args, in_batched)]
        out = jax.vmap(_conflicts_dense if axis_size <= DENSE_BATCH else _conflicts_sparse)(*args)
        return out, True

    return f(px, py, ph, alive)


def _close(dx, dy):
    """The bounding-circle pre-check on centre offsets: not more than a vehicle length apart."""
    return ~(jnp.sqrt(dx * dx + dy * dy) > Veh.LENGTH)


def _near(px, py):
    """The pre-check for every pair, ``[T, i, j]``."""
    x, y = px.T, py.T
    return _close(x[:, None, :] - x[:, :, None], y[:, None, :] - y[:, :, None])  # j's centre minus i's


def _conflicts_dense(px, py, ph, alive):
    """:func:`conflicts` testing every pair: ``[T, V, V, 9]`` points."""
    def at_time(xyh):  # every slot's predicted rectangle at one time: heading cosine, sine and its 9 points
        x, y, h = xyh
        s, c = trig.sin_cos(h)
        return (c, s) + _corners(x, y, c, s)

    # one time per loop iteration: the loop's outputs are materialised, so the [T, V, V, 9] tests below read them
    # (as one expression XLA would redo the sines and cosines for every pair)
    c, s, cx, cy = jax.lax.map(at_time, (px.T, py.T, ph.T))  # [T, V], [T, V], [T, V, 9], [T, V, 9]
    x, y = px.T, py.T
    # [T, i, j]: a point of i's rectangle inside j's; j's points inside i's rectangle is its transpose
    i_in_j = jnp.any(_inside(cx[:, :, None], cy[:, :, None], x[:, None, :], y[:, None, :], c[:, None, :],
                             s[:, None, :]), axis=-1)
    hit = jnp.any(_near(px, py) & (i_in_j | jnp.swapaxes(i_in_j, 1, 2)), axis=0)
    return hit & alive[:, None] & alive[None, :] & ~jnp.eye(px.shape[0], dtype=bool)


def _conflicts_sparse(px, py, ph, alive):
    """:func:`conflicts` with the rectangle test only for the live pairs that pass the pre-check at some time
    (:func:`envs_jax.sparse.sparse_map`, for use under ``vmap``)."""
    n = px.shape[0]
    iu, ju = (a.astype(np.int32) for a in np.triu_indices(n, 1))
    candidate = jnp.any(_near(px, py), axis=0)[iu, ju] & alive[iu] & alive[ju]
    candidate = materialize(candidate)  # once: sparse_map's packing reads it in another order

    def rectangle(r):  # one vehicle's rows [T, 4]: centre, heading cosine and sine, the 9 points [T, 9]
        x, y, c, s = r[:, 0], r[:, 1], r[:, 2], r[:, 3]
        return (x, y, c, s) + _corners(x, y, c, s)

    def pair(a, b):  # a candidate pair's predictions: a point of one rectangle inside the other at a near time
        ax, ay, ac, as_, acx, acy = rectangle(a)
        bx, by, bc, bs, bcx, bcy = rectangle(b)
        near_t = _close(bx - ax, by - ay)
        a_in_b = jnp.any(_inside(acx, acy, bx, by, bc, bs), axis=-1)
        b_in_a = jnp.any(_inside(bcx, bcy, ax, ay, ac, as_), axis=-1)
        return jnp.any(near_t & (a_in_b | b_in_a))

    # [V, T, 4]: each slot's trigonometry once (not per pair); the pairs' rows are gathered only where needed
    sin_h, cos_h = trig.sin_cos(ph)
    table = jnp.stack([px, py, cos_h, sin_h], axis=-1)
    fraction = min(1 / 32, CONFLICT_ROWS_PER_VEHICLE * n / max(len(iu), 1))
    hit = sparse_map(pair, candidate, TableRows(table, jnp.asarray(iu)), TableRows(table, jnp.asarray(ju)),
                     fraction=fraction)
    upper = jnp.zeros((n, n), bool).at[iu, ju].set(hit)
    return upper | upper.T


def yielding_side(priority, x, y, heading):
    """``respect_priorities(v_i, v_j)`` for every pair: True where ``v_i`` yields to ``v_j`` (``[V, V]``)."""
    pi, pj = priority[:, None], priority[None, :]
    s, c = trig.sin_cos(heading)
    dx, dy = x[None, :] - x[:, None], y[None, :] - y[:, None]
    front_ij = c[:, None] * dx + s[:, None] * dy  # v_i.front_distance_to(v_j)
    front_ji = -(c[None, :] * dx + s[None, :] * dy)  # v_j.front_distance_to(v_i)
    return jnp.where(pi != pj, pi < pj, front_ij > front_ji)


def enforce_road_rules(road: Road, st: TrafficState, yielding, yield_timer, priority, is_idm, order=None,
                       prediction=None):
    """One ``enforce_road_rules``: ``(target_speed, yielding, yield_timer)`` after releases and new yields.

    ``priority``: static ``[lanes]`` lane priorities; ``is_idm``: static ``[V]`` flags of the slots
    that can be made to yield; ``order``: ``[V]`` positions in ``road.vehicles`` (default: slot order),
    which decide the pair's ``v1`` and so the vehicle that yields on an exact front-distance tie
    (vehicles face to face on one axis-aligned line); ``prediction``: the ``(x, y, heading)`` ``[V, T]``
    predictions at ``PREDICTION_TIMES`` (default :func:`predict_along_route` for every slot).
    """
    speed_limit = road.lanes.col("speed_limit")[st.lane]
    release = st.alive & yielding & (yield_timer >= YIELD_DURATION * REGULATION_FREQUENCY)
    target_speed = jnp.where(release, speed_limit, st.target_speed)
    yield_timer = jnp.where(st.alive & yielding & ~release, yield_timer + 1, yield_timer)
    yielding = yielding & ~release

    times = jnp.asarray(PREDICTION_TIMES, st.x.dtype)
    px, py, ph = predict_along_route(road, st, times) if prediction is None else prediction
    n = st.x.shape[0]
    if order is None:
        upper = jnp.asarray(np.triu(np.ones((n, n), bool), 1))
    else:
        upper = order[:, None] < order[None, :]
    pair = upper & conflicts(px, py, ph, st.alive)  # live pairs only
    prio = jnp.asarray(priority)[st.lane]
    i_yields = yielding_side(prio, st.x, st.y, st.heading)
    stops = jnp.any(pair & i_yields, axis=1) | jnp.any(pair & ~i_yields, axis=0)
    stops = stops & jnp.asarray(is_idm)
    target_speed = jnp.where(stops, 0.0, target_speed).astype(st.x.dtype)
    yielding = yielding | stops
    yield_timer = jnp.where(stops, 0, yield_timer)
    return target_speed, yielding, yield_timer
