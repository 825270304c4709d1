"""The simulator's closest-lane search, batch-minor (:func:`locate`), and the local coordinates it carries from
frame to frame (:func:`circle_coords`, :func:`lane_coords`).

Under ``vmap`` the all-lane queries (:mod:`envs_jax.all_lanes`) build ``[batch, ..., L]`` arrays and reduce them
along the minor lane axis, a slow pattern on CPU. ``locate`` has its own batching rule
that flattens the batch and works on ``[L, n]`` arrays (lanes major, poses minor), so the
lane reductions are elementwise minima across rows, vectorised over the poses. Same
per-lane formulas as ``local_coordinates_all`` / ``distance_with_heading_all``.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import sparse, trig
from envs_jax.all_lanes import distance_with_heading_all, first_argmin
from envs_jax.lanes import (
    CIRCULAR,
    FIELDS,
    SINE,
    LaneTable,
    distance_from_coords,
    float_dtype,
    linear_local,
    sine_offset,
    wrap_to_pi,
)
from envs_jax.materialize import materialize

__all__ = ["locate", "circle_coords", "lane_coords", "sine_lower_bound", "SMALL_BATCH", "BOUND_SLACK_ABS",
           "BOUND_SLACK_REL"]


# Slack of the sine-lane lower bound (m + rad): far above the round-off of the costs, so a
# sine lane is skipped only when its exact cost is certainly above the best other lane's.
BOUND_SLACK_ABS = 1e-2
BOUND_SLACK_REL = 1e-5


def _cols(lanes: LaneTable, rows, names):
    """Columns ``names`` of the lanes ``rows`` as ``[len(rows), 1]`` constants."""
    return {name: lanes.col(name, np.asarray(rows, dtype=np.int32))[:, None] for name in names}


def circle_coords(lanes: LaneTable, px, py):
    """Polar coordinates ``(phi, radius)`` of a point around every circle centre (``[..., C]``).

    With them, the local coordinates on any lane need no further trigonometry except a
    sine lane's offset (:func:`lane_coords`); the simulator carries them from one frame
    to the next instead of all-lane coordinates. ``C`` may be 0.
    """
    px = jnp.asarray(px)[..., None]
    py = jnp.asarray(py)[..., None]
    centers = jnp.asarray(lanes.circle_centers, dtype=float_dtype()).reshape(-1, 2)
    dx = px - centers[:, 0]
    dy = py - centers[:, 1]
    return trig.arctan2(dy, dx), jnp.sqrt(dx * dx + dy * dy)


def _circular_from_polar(r, phi_c, radius_c):
    phi = r["start_phase"] + wrap_to_pi(phi_c - r["start_phase"])
    s = r["cdir"] * (phi - r["start_phase"]) * r["radius"]
    lat = r["cdir"] * (r["radius"] - radius_c)
    return s, lat


def _pick_column(values, c):
    """``values[..., c]`` over a few static columns (circle centres, sine lanes) as a chain of selections:
    it broadcasts ``c`` against ``values[..., j]`` without gathering at the broadcast shape."""
    out = values[..., 0]
    for j in range(1, values.shape[-1]):
        out = jnp.where(c == j, values[..., j], out)
    return out


def lane_coords(lanes: LaneTable, px, py, circles, idx, sine: bool = True):
    """Exact ``(s, lat)`` of a point on lane ``idx`` (table row, traced; ``idx`` and ``px``
    broadcast together), given its :func:`circle_coords` ``circles`` (``([..., C], [..., C])``,
    ``[...]`` like ``px``). The lane rows are gathered at ``idx``'s own shape, so many points
    on few lanes (``idx [Q, 1]``, ``px [N]``) cost ``Q`` row gathers, not ``Q N``.
    ``sine=False`` leaves a sine lane's lateral coordinate measured from its base line."""
    sine = sine and lanes.sine_rows.size > 0
    names = ["start_x", "start_y", "dir_x", "dir_y", "lat_x", "lat_y"]
    names += ["amplitude", "pulsation", "phase"] if sine else []
    names += ["start_phase", "cdir", "radius"] if lanes.circular_rows.size else []
    r = lanes.columns(idx, names)
    kind = jnp.asarray(lanes.kind)[idx]
    s, lat = linear_local(r, px, py)
    if sine:
        lat = jnp.where(kind == SINE, lat - sine_offset(r, s), lat)
    if lanes.circular_rows.size:
        c = jnp.asarray(np.maximum(lanes.circle_of_lane, 0))[idx]
        phi_c, radius_c = _pick_column(circles[0], c), _pick_column(circles[1], c)
        s_c, lat_c = _circular_from_polar(r, phi_c, radius_c)
        circ = kind == CIRCULAR
        s, lat = jnp.where(circ, s_c, s), jnp.where(circ, lat_c, lat)
    return s, lat


def sine_offsets(lanes: LaneTable, px, py, idx):
    """The sine-lane offset ``A sin(w s + phi)`` of each point ``(px, py)`` (``[N]``) on lane ``idx`` (table
    rows, ``[..., 1]``): ``[..., N]``, 0 where ``idx`` is not a sine lane. The offsets are computed once per point
    and sine lane (``[N, S]``) and picked per lane, where :func:`lane_coords` would evaluate a sine per point and
    lane of ``idx``; subtracted from ``lane_coords(..., sine=False)``'s lateral coordinate they give its exact
    ``sine=True`` value. Needs a road with sine lanes."""
    r = {k: v[:, 0] for k, v in _cols(lanes, lanes.sine_rows, ("start_x", "start_y", "dir_x", "dir_y", "lat_x",
                                                              "lat_y", "amplitude", "pulsation", "phase")).items()}
    s, _ = linear_local(r, jnp.asarray(px)[..., None], jnp.asarray(py)[..., None])
    offsets = sine_offset(r, s)  # [N, S]
    which = jnp.asarray(lanes.sine_of_lane)[idx]
    return _pick_column(offsets, which), which >= 0


def sine_lower_bound(r, s, lat_base, heading):
    """Lower bound of a sine lane's distance-with-heading from ``s`` and the lateral coordinate
    ``lat_base`` measured from its straight base line: its centre line stays within ``|A|`` of
    the base line and its heading within ``arctan(|A w|)`` of the base heading, so the cost is
    at least ``max(|lat_base| - |A|, 0) + (s out of range) + max(|wrap(psi - heading)| - arctan(|A w|), 0)``."""
    slope = trig.arctan(jnp.abs(r["amplitude"] * r["pulsation"]))
    return (jnp.maximum(jnp.abs(lat_base) - jnp.abs(r["amplitude"]), 0) + distance_from_coords(r["length"], s, 0.0)
            + jnp.maximum(jnp.abs(wrap_to_pi(heading - r["heading"])) - slope, 0))


def _first_min(cost, rows, size):
    """Least cost over axis 0 and the first table row attaining it (``first_argmin``: with a
    NaN cost, never in a valid state, the last row ``size - 1``)."""
    best = jnp.min(cost, axis=0)
    row = jnp.min(jnp.where(cost == best, jnp.asarray(rows, jnp.int32)[:, None], size - 1), axis=0)
    return best, row


def _sine_family(lanes: LaneTable, px, py, heading):
    """Exact cost on every sine lane for one pose: the least, its first table row and the
    lateral coordinate on that lane."""
    r = {k: v[:, 0] for k, v in _cols(lanes, lanes.sine_rows, FIELDS).items()}
    s, lat = linear_local(r, px, py)
    lat = lat - sine_offset(r, s)
    h = r["heading"] + trig.arctan(r["amplitude"] * r["pulsation"] * trig.cos(r["pulsation"] * s + r["phase"]))
    cost = distance_from_coords(r["length"], s, lat) + jnp.abs(wrap_to_pi(heading - h))
    # materialised once: otherwise XLA recomputes the sine in each consumer
    cost, lat = materialize((cost, lat))
    best, row = _first_min(cost[:, None], lanes.sine_rows, lanes.size)
    return best[0], row[0], jnp.sum(jnp.where(jnp.asarray(lanes.sine_rows) == row, lat, 0), axis=0)


def _locate_flat(lanes: LaneTable, px, py, heading):
    """:func:`locate` on flat ``[n]`` poses, lanes major (``[L, n]`` arrays)."""
    circles = circle_coords(lanes, px, py)  # [n, C]
    phi_t, radius_t = circles[0].T, circles[1].T  # [C, n]
    costs, rows = [], []
    if lanes.straight_rows.size:
        r = _cols(lanes, lanes.straight_rows, ("start_x", "start_y", "dir_x", "dir_y", "lat_x", "lat_y",
                                               "length", "heading"))
        s, lat = linear_local(r, px, py)
        costs.append(distance_from_coords(r["length"], s, lat) + jnp.abs(wrap_to_pi(heading - r["heading"])))
        rows.append(lanes.straight_rows)
    if lanes.circular_rows.size:
        r = _cols(lanes, lanes.circular_rows, ("start_phase", "cdir", "radius", "length"))
        c = lanes.circle_of_row
        s, lat = _circular_from_polar(r, phi_t[c], radius_t[c])
        h = r["cdir"] * s / r["radius"] + r["start_phase"] + jnp.pi / 2 * r["cdir"]
        costs.append(distance_from_coords(r["length"], s, lat) + jnp.abs(wrap_to_pi(heading - h)))
        rows.append(lanes.circular_rows)
    if costs:
        best, lane = _first_min(jnp.concatenate(costs, axis=0), np.concatenate(rows), lanes.size)
        s, lat = lane_coords(lanes, px, py, circles, lane, sine=False)
    else:  # only sine lanes
        best = jnp.full(px.shape, jnp.inf, px.dtype)
        lane = jnp.full(px.shape, lanes.size - 1, jnp.int32)
        s = lat = jnp.zeros_like(px)
    if lanes.sine_rows.size:
        r = _cols(lanes, lanes.sine_rows, ("start_x", "start_y", "dir_x", "dir_y", "lat_x", "lat_y", "length",
                                           "heading", "amplitude", "pulsation"))
        s_sine, lat_base = linear_local(r, px, py)
        bound = sine_lower_bound(r, s_sine, lat_base, heading)
        lowest = functools.reduce(jnp.minimum, list(bound))  # elementwise: one fused loop, no reduce
        need = lowest <= best + (BOUND_SLACK_ABS + BOUND_SLACK_REL * jnp.abs(best))
        sine_best, sine_lane, sine_lat = sparse.packed_rows(
            jax.vmap(lambda x, y, h: _sine_family(lanes, x, y, h)), need, px, py, heading,
            fraction=1 / 4)  # above the share of vehicle frames near a sine lane (docs/performance.md)
        # the sine lane wins if strictly better, or if equal and first in table order
        take = need & ((sine_best < best) | ((sine_best == best) & (sine_lane < lane)))
        lane = jnp.where(take, sine_lane, lane)
        s_sine_lane, _ = lane_coords(lanes, px, py, circles, lane, sine=False)
        s = jnp.where(take, s_sine_lane, s)
        lat = jnp.where(take, sine_lat, lat)
    return lane, s, lat, circles


SMALL_BATCH = 8  # up to this many poses in all, locate runs the all-lane search (_locate_dense)


def _locate_dense(lanes: LaneTable, px, py, heading):
    """:func:`locate` by the all-lane search (``first_argmin`` of :func:`distance_with_heading_all`)."""
    cost, s_all, lat_all = distance_with_heading_all(lanes, px, py, heading)
    lane = first_argmin(cost)
    pick = lambda a: jnp.take_along_axis(a, lane[..., None], axis=-1)[..., 0]
    return lane, pick(s_all), pick(lat_all), circle_coords(lanes, px, py)


def locate(lanes: LaneTable, px, py, heading):
    """Closest lane of a pose (``get_closest_lane_index``: the first lane in table order with the
    least distance-with-heading), the exact ``(s, lat)`` on it, and :func:`circle_coords`.

    Same lane as ``first_argmin`` of :func:`distance_with_heading_all` (tests/test_locate.py),
    cheaper: straight and circular lanes cost no trigonometry beyond one ``atan2`` per
    circle centre; the sine lanes' (sin, cos, arctan) runs only for the poses where some
    sine lane's :func:`sine_lower_bound` is within a slack of the best other cost, packed
    (``sparse.packed_rows``); elsewhere no sine lane can be the closest or tie with it.
    Under ``vmap`` (custom rule) the whole batch is flattened and the lanes are laid out
    major; with at most ``SMALL_BATCH`` poses in all (one to four envs), where the cost is
    the number of XLA ops rather than arithmetic, the all-lane search runs instead. Shapes: ``px, py, heading``
    ``[...]``; returns ``lane, s, lat`` ``[...]`` and
    ``circles`` (``[..., C]`` each).
    """
    px, py, heading = jnp.broadcast_arrays(jnp.asarray(px), jnp.asarray(py), jnp.asarray(heading))
    shape = px.shape

    def run(n_lead, px, py, heading):
        if px.size <= SMALL_BATCH:  # a few poses: the all-lane search runs fewer (per-op bound) ops
            out = _locate_dense(lanes, px.reshape(-1), py.reshape(-1), heading.reshape(-1))
        else:
            out = _locate_flat(lanes, px.reshape(-1), py.reshape(-1), heading.reshape(-1))
        lead = n_lead + shape
        lane, s, lat, (phi, rad) = out
        return (lane.reshape(lead), s.reshape(lead), lat.reshape(lead),
                (phi.reshape(lead + phi.shape[-1:]), rad.reshape(lead + rad.shape[-1:])))

    f = jax.custom_batching.custom_vmap(lambda px, py, heading: run((), px, py, heading))

    @f.def_vmap
    def rule(axis_size, in_batched, px, py, heading):
        full = lambda a, b: a if b else jnp.broadcast_to(a, (axis_size,) + a.shape)
        out = run((axis_size,), *(full(a, b) for a, b in zip((px, py, heading), in_batched)))
        return out, jax.tree_util.tree_map(lambda _: True, out)

    return f(px, py, heading)
