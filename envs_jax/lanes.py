"""Lane geometry: straight, sine and circular lanes on one padded table.

Every lane of a scenario is one row of a :class:`LaneTable`. The table is
built on the host in float64 with exactly the arithmetic of highway-env's
``StraightLane``, ``SineLane`` and ``CircularLane`` constructors, and is turned
into JAX constants at trace time (so it follows ``jax_enable_x64``).

Two kinds of query exist:

* single-lane queries (``local_coordinates``, ``position``, ``heading_at``,
  ...) take a traced lane index and evaluate the three lane formulas on the
  gathered row, selecting the right one with ``jnp.where``;
* all-lane queries (``local_coordinates_all``) evaluate each lane family only on
  its own rows (a static partition of the table) and scatter the results back
  into table order, so the closest-lane search costs one pass per family;
* ``locate`` (the simulator's closest-lane search) evaluates the lanes one by one
  (unrolled, fused by XLA into one loop over the batch) and the sine lanes'
  trigonometry only for the points where a cheap lower bound says a sine lane could
  be the closest (``sparse_map``).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import sparse

STRAIGHT, SINE, CIRCULAR = 0, 1, 2

# highway-env LineType values, kept for rendering.
LINE_NONE, LINE_STRIPED, LINE_CONTINUOUS, LINE_CONTINUOUS_LINE = 0, 1, 2, 3

DEFAULT_WIDTH = 4.0
VEHICLE_LENGTH = 5.0  # AbstractLane.VEHICLE_LENGTH: margins of on_lane / after_end / reachable

# Columns of the float table. Straight and sine lanes use start..phase; circular
# lanes use center..cdir. Unused columns are zero.
_FIELDS = (
    "start_x", "start_y", "end_x", "end_y", "dir_x", "dir_y", "lat_x", "lat_y",
    "heading", "length", "width", "amplitude", "pulsation", "phase",
    "center_x", "center_y", "radius", "start_phase", "end_phase", "cdir",
    "speed_limit",
)
_COL = {name: i for i, name in enumerate(_FIELDS)}


@dataclasses.dataclass(frozen=True)
class LaneSpec:
    """One lane, as highway-env constructs it (host side, float64)."""

    kind: int
    values: tuple  # len(_FIELDS) floats
    forbidden: bool
    line_types: tuple[int, int]


def straight(start, end, width=DEFAULT_WIDTH, line_types=(LINE_STRIPED, LINE_STRIPED),
             forbidden=False, speed_limit=20.0) -> LaneSpec:
    """``StraightLane(start, end)``: heading, length and unit vectors as highway-env computes them."""
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(end, dtype=np.float64)
    heading = np.arctan2(end[1] - start[1], end[0] - start[0])
    length = np.linalg.norm(end - start)
    direction = (end - start) / length
    lateral = np.array([-direction[1], direction[0]])
    row = dict(start_x=start[0], start_y=start[1], end_x=end[0], end_y=end[1],
               dir_x=direction[0], dir_y=direction[1], lat_x=lateral[0], lat_y=lateral[1],
               heading=heading, length=length, width=width, speed_limit=speed_limit)
    return _spec(STRAIGHT, row, forbidden, line_types)


def sine(start, end, amplitude, pulsation, phase, width=DEFAULT_WIDTH,
         line_types=(LINE_STRIPED, LINE_STRIPED), forbidden=False, speed_limit=20.0) -> LaneSpec:
    """``SineLane``: a straight lane whose centre line is offset by ``A sin(w s + phase)``."""
    base = straight(start, end, width, line_types, forbidden, speed_limit)
    row = dict(zip(_FIELDS, base.values))
    row.update(amplitude=amplitude, pulsation=pulsation, phase=phase)
    return _spec(SINE, row, forbidden, line_types)


def circular(center, radius, start_phase, end_phase, clockwise=True, width=DEFAULT_WIDTH,
             line_types=(LINE_STRIPED, LINE_STRIPED), forbidden=False, speed_limit=20.0) -> LaneSpec:
    """``CircularLane``: arc of ``radius`` around ``center`` from ``start_phase`` to ``end_phase``."""
    cdir = 1.0 if clockwise else -1.0
    length = radius * (end_phase - start_phase) * cdir
    row = dict(center_x=center[0], center_y=center[1], radius=radius, start_phase=start_phase,
               end_phase=end_phase, cdir=cdir, length=length, width=width, speed_limit=speed_limit)
    return _spec(CIRCULAR, row, forbidden, line_types)


def _spec(kind, row, forbidden, line_types) -> LaneSpec:
    values = tuple(float(row.get(name, 0.0)) for name in _FIELDS)
    return LaneSpec(kind=kind, values=values, forbidden=bool(forbidden),
                    line_types=tuple(int(t) for t in line_types))


def float_dtype():
    """The working float dtype: float64 under ``jax_enable_x64``, else float32.

    Host tables are converted with an explicit dtype: JAX 0.10 may otherwise reuse a
    float64 constant from an earlier x64 trace of the same numpy array.
    """
    return jax.dtypes.canonicalize_dtype(np.float64)


class LaneTable:
    """All lanes of a road, padded into one float64 table (rows in road-network order).

    Host-side object: its arrays are numpy; ``col(name)`` returns a JAX constant
    of the current default float dtype, created when traced.
    """

    def __init__(self, specs: Sequence[LaneSpec]):
        if not specs:
            raise ValueError("a lane table needs at least one lane")
        self.size = len(specs)
        self.kind = np.array([s.kind for s in specs], dtype=np.int32)
        self.forbidden = np.array([s.forbidden for s in specs], dtype=bool)
        self.line_types = np.array([s.line_types for s in specs], dtype=np.int32)
        self.table = np.array([s.values for s in specs], dtype=np.float64)
        # Static partition used by the all-lane queries.
        self.linear_rows = np.nonzero(self.kind != CIRCULAR)[0].astype(np.int32)
        self.sine_rows_in_linear = np.nonzero(self.kind[self.linear_rows] == SINE)[0].astype(np.int32)
        self.circular_rows = np.nonzero(self.kind == CIRCULAR)[0].astype(np.int32)
        centers = self.table[self.circular_rows][:, [_COL["center_x"], _COL["center_y"]]]
        self.circle_centers, self.circle_of_row = (np.unique(centers, axis=0, return_inverse=True)
                                                   if len(centers) else (np.zeros((0, 2)), np.zeros(0, np.int64)))
        self.circle_of_row = self.circle_of_row.reshape(-1).astype(np.int32)
        self.circle_of_lane = -np.ones(self.size, dtype=np.int32)  # table row -> circle centre (-1: none)
        self.circle_of_lane[self.circular_rows] = self.circle_of_row
        order = np.concatenate([self.linear_rows, self.circular_rows])
        self._unpermute = np.argsort(order).astype(np.int32)  # family-concatenated -> table order
        self.straight_rows = np.nonzero(self.kind == STRAIGHT)[0].astype(np.int32)
        self.sine_rows = np.nonzero(self.kind == SINE)[0].astype(np.int32)

    def np_col(self, name: str) -> np.ndarray:
        return self.table[:, _COL[name]]

    def col(self, name: str, rows=None):
        values = self.table[:, _COL[name]] if rows is None else self.table[rows, _COL[name]]
        return jnp.asarray(values, dtype=float_dtype())

    def row(self, idx):
        """Gather lane ``idx`` (traced int, any shape) as a dict of JAX arrays."""
        table = jnp.asarray(self.table, dtype=float_dtype())
        gathered = table[idx]
        out = {name: gathered[..., i] for i, name in enumerate(_FIELDS)}
        out["kind"] = jnp.asarray(self.kind)[idx]
        out["forbidden"] = jnp.asarray(self.forbidden)[idx]
        return out


# --------------------------------------------------------------------------------------------
# Elementary formulas (highway-env lane.py), on dicts of arrays that broadcast together.


def wrap_to_pi(x):
    """``utils.wrap_to_pi``: ((x + pi) mod 2 pi) - pi.

    Written with ``floor`` rather than ``mod``: XLA lowers ``mod`` to a scalar
    ``fmod`` call on CPU, much slower, and the two agree to round-off.
    """
    y = x + jnp.pi
    return y - 2 * jnp.pi * jnp.floor(y / (2 * jnp.pi)) - jnp.pi


def _linear_local(r, px, py):
    dx = px - r["start_x"]
    dy = py - r["start_y"]
    s = dx * r["dir_x"] + dy * r["dir_y"]
    lat = dx * r["lat_x"] + dy * r["lat_y"]
    return s, lat


def _sine_offset(r, s):
    return r["amplitude"] * jnp.sin(r["pulsation"] * s + r["phase"])


def _circular_local(r, px, py):
    dx = px - r["center_x"]
    dy = py - r["center_y"]
    phi = jnp.arctan2(dy, dx)
    phi = r["start_phase"] + wrap_to_pi(phi - r["start_phase"])
    radius = jnp.sqrt(dx * dx + dy * dy)
    s = r["cdir"] * (phi - r["start_phase"]) * r["radius"]
    lat = r["cdir"] * (r["radius"] - radius)
    return s, lat


def local_coordinates(lanes: LaneTable, idx, px, py):
    """World position -> (longitudinal, lateral) on lane ``idx`` (``lane.local_coordinates``)."""
    r = lanes.row(idx)
    s_lin, lat_lin = _linear_local(r, px, py)
    lat_lin = jnp.where(r["kind"] == SINE, lat_lin - _sine_offset(r, s_lin), lat_lin)
    s_cir, lat_cir = _circular_local(r, px, py)
    circ = r["kind"] == CIRCULAR
    return jnp.where(circ, s_cir, s_lin), jnp.where(circ, lat_cir, lat_lin)


def position(lanes: LaneTable, idx, s, lat):
    """(longitudinal, lateral) on lane ``idx`` -> world position (``lane.position``)."""
    r = lanes.row(idx)
    lat_lin = jnp.where(r["kind"] == SINE, lat + _sine_offset(r, s), lat)
    x_lin = r["start_x"] + s * r["dir_x"] + lat_lin * r["lat_x"]
    y_lin = r["start_y"] + s * r["dir_y"] + lat_lin * r["lat_y"]
    phi = r["cdir"] * s / jnp.where(r["radius"] == 0, 1.0, r["radius"]) + r["start_phase"]
    rad = r["radius"] - lat * r["cdir"]
    x_cir = r["center_x"] + rad * jnp.cos(phi)
    y_cir = r["center_y"] + rad * jnp.sin(phi)
    circ = r["kind"] == CIRCULAR
    return jnp.where(circ, x_cir, x_lin), jnp.where(circ, y_cir, y_lin)


def _heading_from_row(r, s):
    sine_term = jnp.arctan(r["amplitude"] * r["pulsation"] * jnp.cos(r["pulsation"] * s + r["phase"]))
    h_lin = jnp.where(r["kind"] == SINE, r["heading"] + sine_term, r["heading"])
    radius = jnp.where(r["radius"] == 0, 1.0, r["radius"])
    h_cir = r["cdir"] * s / radius + r["start_phase"] + jnp.pi / 2 * r["cdir"]
    return jnp.where(r["kind"] == CIRCULAR, h_cir, h_lin)


def heading_at(lanes: LaneTable, idx, s):
    """Lane heading at longitudinal coordinate ``s`` (``lane.heading_at``)."""
    return _heading_from_row(lanes.row(idx), s)


def on_lane_coords(lane_length, lane_width, s, lat):
    """``lane.on_lane``: |lat| <= width/2 and -5 <= s < length + 5."""
    return (jnp.abs(lat) <= lane_width / 2) & (-VEHICLE_LENGTH <= s) & (s < lane_length + VEHICLE_LENGTH)


def on_lane(lanes: LaneTable, idx, px, py):
    s, lat = local_coordinates(lanes, idx, px, py)
    r = lanes.row(idx)
    return on_lane_coords(r["length"], r["width"], s, lat)


def after_end(lanes: LaneTable, idx, px, py):
    """``lane.after_end``: s > length - VEHICLE_LENGTH / 2."""
    s, _ = local_coordinates(lanes, idx, px, py)
    return s > lanes.row(idx)["length"] - VEHICLE_LENGTH / 2


def is_reachable_from(lanes: LaneTable, idx, px, py):
    """``lane.is_reachable_from``: not forbidden, |lat| <= 2 width, 0 <= s < length + 5."""
    s, lat = local_coordinates(lanes, idx, px, py)
    r = lanes.row(idx)
    close = (jnp.abs(lat) <= 2 * r["width"]) & (0 <= s) & (s < r["length"] + VEHICLE_LENGTH)
    return close & ~r["forbidden"]


def distance_from_coords(lane_length, s, lat):
    """``lane.distance``: |lat| + max(s - L, 0) + max(-s, 0)."""
    return jnp.abs(lat) + jnp.maximum(s - lane_length, 0) + jnp.maximum(0 - s, 0)


def distance(lanes: LaneTable, idx, px, py):
    s, lat = local_coordinates(lanes, idx, px, py)
    return distance_from_coords(lanes.row(idx)["length"], s, lat)


# --------------------------------------------------------------------------------------------
# All lanes at once.


def local_coordinates_all(lanes: LaneTable, px, py, with_heading: bool = True):
    """(s, lat, heading_at(s)) of a point on every lane, shape ``[..., L]`` in table order.

    Each lane family is evaluated only on its own rows; a static permutation puts
    the results back in table order (which decides highway-env's tie-breaking).
    """
    px = jnp.asarray(px)[..., None]
    py = jnp.asarray(py)[..., None]
    parts_s, parts_lat, parts_h = [], [], []
    if lanes.linear_rows.size:
        rows = lanes.linear_rows
        r = {name: lanes.col(name, rows) for name in _FIELDS}
        s, lat = _linear_local(r, px, py)
        h = jnp.broadcast_to(r["heading"], s.shape)
        if lanes.sine_rows_in_linear.size:
            sub = lanes.sine_rows_in_linear
            rs = {name: v[sub] for name, v in r.items()}
            s_sin = s[..., sub]
            lat = lat.at[..., sub].add(-_sine_offset(rs, s_sin))
            if with_heading:
                h = h.at[..., sub].add(jnp.arctan(rs["amplitude"] * rs["pulsation"]
                                                  * jnp.cos(rs["pulsation"] * s_sin + rs["phase"])))
        parts_s.append(s)
        parts_lat.append(lat)
        parts_h.append(h)
    if lanes.circular_rows.size:
        rows = lanes.circular_rows
        r = {name: lanes.col(name, rows) for name in _FIELDS}
        # atan2 and the radius once per distinct centre (all ring lanes share one).
        centers = jnp.asarray(lanes.circle_centers, dtype=float_dtype())
        dx = px - centers[:, 0]
        dy = py - centers[:, 1]
        phi_c = jnp.arctan2(dy, dx)[..., lanes.circle_of_row]
        radius_c = jnp.sqrt(dx * dx + dy * dy)[..., lanes.circle_of_row]
        phi = r["start_phase"] + wrap_to_pi(phi_c - r["start_phase"])
        s = r["cdir"] * (phi - r["start_phase"]) * r["radius"]
        lat = r["cdir"] * (r["radius"] - radius_c)
        h = r["cdir"] * s / r["radius"] + r["start_phase"] + jnp.pi / 2 * r["cdir"]
        parts_s.append(s)
        parts_lat.append(lat)
        parts_h.append(h)
    if len(parts_s) == 1:
        return parts_s[0], parts_lat[0], parts_h[0]
    perm = lanes._unpermute
    cat = lambda parts: jnp.concatenate(parts, axis=-1)[..., perm]
    return cat(parts_s), cat(parts_lat), cat(parts_h)


def first_argmin(cost):
    """``argmin`` over the last axis (first index on ties), as two plain reductions.

    A minimum, then the smallest index attaining it: XLA's CPU backend vectorises
    these, whereas ``argmin`` (a variadic reduction) runs as a scalar loop. (With a NaN
    cost, which a valid state never has, it returns the last index.)
    """
    best = jnp.min(cost, axis=-1, keepdims=True)
    index = jnp.arange(cost.shape[-1], dtype=jnp.int32)
    return jnp.min(jnp.where(cost == best, index, cost.shape[-1] - 1), axis=-1)


def distance_with_heading_all(lanes: LaneTable, px, py, heading):
    """``lane.distance_with_heading`` for every lane: |lat| + out-of-range s + |wrap(psi - psi_lane(s))|."""
    s, lat, lane_heading = local_coordinates_all(lanes, px, py)
    angle = jnp.abs(wrap_to_pi(jnp.asarray(heading)[..., None] - lane_heading))
    return distance_from_coords(lanes.col("length"), s, lat) + angle, s, lat


# --------------------------------------------------------------------------------------------
# Closest lane, batch-minor (the simulator's path).
#
# Under ``vmap`` the all-lane queries above build ``[batch, ..., L]`` arrays and reduce them
# along the minor lane axis, a slow pattern on CPU. ``locate`` has its own batching rule
# that flattens the batch and works on ``[L, n]`` arrays (lanes major, poses minor), so the
# lane reductions are elementwise minima across rows, vectorised over the poses. Same
# per-lane formulas as ``local_coordinates_all`` / ``distance_with_heading_all``.

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
    return jnp.arctan2(dy, dx), jnp.sqrt(dx * dx + dy * dy)


def _circular_from_polar(r, phi_c, radius_c):
    phi = r["start_phase"] + wrap_to_pi(phi_c - r["start_phase"])
    s = r["cdir"] * (phi - r["start_phase"]) * r["radius"]
    lat = r["cdir"] * (r["radius"] - radius_c)
    return s, lat


def _pick_circle(values, c):
    """``values[..., c]`` over the (few, static) circle centres as a chain of selections: it
    broadcasts ``c`` against ``values[..., j]`` without gathering at the broadcast shape."""
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
    table = jnp.asarray(lanes.table[:, [_COL[n] for n in names]], dtype=float_dtype())[idx]
    r = {n: table[..., i] for i, n in enumerate(names)}
    kind = jnp.asarray(lanes.kind)[idx]
    s, lat = _linear_local(r, px, py)
    if sine:
        lat = jnp.where(kind == SINE, lat - _sine_offset(r, s), lat)
    if lanes.circular_rows.size:
        c = jnp.asarray(np.maximum(lanes.circle_of_lane, 0))[idx]
        phi_c, radius_c = _pick_circle(circles[0], c), _pick_circle(circles[1], c)
        s_c, lat_c = _circular_from_polar(r, phi_c, radius_c)
        circ = kind == CIRCULAR
        s, lat = jnp.where(circ, s_c, s), jnp.where(circ, lat_c, lat)
    return s, lat


def sine_lower_bound(r, s, lat_base, heading):
    """Lower bound of a sine lane's distance-with-heading from ``s`` and the lateral coordinate
    ``lat_base`` measured from its straight base line: its centre line stays within ``|A|`` of
    the base line and its heading within ``arctan(|A w|)`` of the base heading, so the cost is
    at least ``max(|lat_base| - |A|, 0) + (s out of range) + max(|wrap(psi - heading)| - arctan(|A w|), 0)``."""
    slope = jnp.arctan(jnp.abs(r["amplitude"] * r["pulsation"]))
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
    r = {k: v[:, 0] for k, v in _cols(lanes, lanes.sine_rows, _FIELDS).items()}
    s, lat = _linear_local(r, px, py)
    lat = lat - _sine_offset(r, s)
    h = r["heading"] + jnp.arctan(r["amplitude"] * r["pulsation"] * jnp.cos(r["pulsation"] * s + r["phase"]))
    cost = distance_from_coords(r["length"], s, lat) + jnp.abs(wrap_to_pi(heading - h))
    # materialised once: otherwise XLA recomputes the sine in each consumer
    cost, lat = jax.lax.optimization_barrier((cost, lat))
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
        s, lat = _linear_local(r, px, py)
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
        s_sine, lat_base = _linear_local(r, px, py)
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
    the number of XLA ops rather than arithmetic, the all-lane search runs instead. Shapes: ``px, py, heading`` ``[...]``; returns ``lane, s, lat`` ``[...]`` and
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
