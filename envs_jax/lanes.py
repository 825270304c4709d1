"""Lane geometry: straight, sine and circular lanes on one padded table.

Every lane of a scenario is one row of a :class:`LaneTable`. The table is
built on the host in float64 with exactly the arithmetic of highway-env's
``StraightLane``, ``SineLane`` and ``CircularLane`` constructors, and is turned
into JAX constants at trace time (so it follows ``jax_enable_x64``).

Here: the table and the single-lane queries (``local_coordinates``, ``position``,
``heading_at``, ...), which take a traced lane index and evaluate the three lane
formulas on the gathered row, selecting the right one with ``jnp.where``. The
queries of every lane at once are in :mod:`envs_jax.all_lanes`; the simulator's
closest-lane search, :func:`envs_jax.lane_locate.locate`, in its own module.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import trig

STRAIGHT, SINE, CIRCULAR = 0, 1, 2

# highway-env LineType values, kept for rendering.
LINE_NONE, LINE_STRIPED, LINE_CONTINUOUS, LINE_CONTINUOUS_LINE = 0, 1, 2, 3

DEFAULT_WIDTH = 4.0
VEHICLE_LENGTH = 5.0  # AbstractLane.VEHICLE_LENGTH: margins of on_lane / after_end / reachable

# Columns of the float table. Straight and sine lanes use start..phase; circular
# lanes use center..cdir. Unused columns are zero.
FIELDS = (
    "start_x", "start_y", "end_x", "end_y", "dir_x", "dir_y", "lat_x", "lat_y",
    "heading", "length", "width", "amplitude", "pulsation", "phase",
    "center_x", "center_y", "radius", "start_phase", "end_phase", "cdir",
    "speed_limit",
)
COLUMN = {name: i for i, name in enumerate(FIELDS)}


@dataclasses.dataclass(frozen=True)
class LaneSpec:
    """One lane, as highway-env constructs it (host side, float64)."""

    kind: int
    values: tuple  # len(FIELDS) floats
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
    row = dict(zip(FIELDS, base.values))
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
    values = tuple(float(row.get(name, 0.0)) for name in FIELDS)
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
        centers = self.table[self.circular_rows][:, [COLUMN["center_x"], COLUMN["center_y"]]]
        self.circle_centers, self.circle_of_row = (np.unique(centers, axis=0, return_inverse=True)
                                                   if len(centers) else (np.zeros((0, 2)), np.zeros(0, np.int64)))
        self.circle_of_row = self.circle_of_row.reshape(-1).astype(np.int32)
        self.circle_of_lane = -np.ones(self.size, dtype=np.int32)  # table row -> circle centre (-1: none)
        self.circle_of_lane[self.circular_rows] = self.circle_of_row
        order = np.concatenate([self.linear_rows, self.circular_rows])
        self.unpermute = np.argsort(order).astype(np.int32)  # family-concatenated -> table order
        self.straight_rows = np.nonzero(self.kind == STRAIGHT)[0].astype(np.int32)
        self.sine_rows = np.nonzero(self.kind == SINE)[0].astype(np.int32)
        self.sine_of_lane = -np.ones(self.size, dtype=np.int32)  # table row -> index among the sine lanes (-1: none)
        self.sine_of_lane[self.sine_rows] = np.arange(self.sine_rows.size, dtype=np.int32)

    def np_col(self, name: str) -> np.ndarray:
        return self.table[:, COLUMN[name]]

    def col(self, name: str, rows=None):
        values = self.table[:, COLUMN[name]] if rows is None else self.table[rows, COLUMN[name]]
        return jnp.asarray(values, dtype=float_dtype())

    def columns(self, idx, names):
        """Only the columns ``names`` of lane ``idx`` (traced int, any shape), gathered at ``idx``'s own shape, as a
        dict of JAX arrays (cheaper than :meth:`row` where few columns are read)."""
        gathered = jnp.asarray(self.table[:, [COLUMN[n] for n in names]], dtype=float_dtype())[idx]
        return {name: gathered[..., i] for i, name in enumerate(names)}

    def row(self, idx):
        """Gather lane ``idx`` (traced int, any shape) as a dict of JAX arrays."""
        table = jnp.asarray(self.table, dtype=float_dtype())
        gathered = table[idx]
        out = {name: gathered[..., i] for i, name in enumerate(FIELDS)}
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


def linear_local(r, px, py):
    dx = px - r["start_x"]
    dy = py - r["start_y"]
    s = dx * r["dir_x"] + dy * r["dir_y"]
    lat = dx * r["lat_x"] + dy * r["lat_y"]
    return s, lat


def sine_offset(r, s):
    return r["amplitude"] * trig.sin(r["pulsation"] * s + r["phase"])


def _circular_local(r, px, py):
    dx = px - r["center_x"]
    dy = py - r["center_y"]
    phi = trig.arctan2(dy, dx)
    phi = r["start_phase"] + wrap_to_pi(phi - r["start_phase"])
    radius = jnp.sqrt(dx * dx + dy * dy)
    s = r["cdir"] * (phi - r["start_phase"]) * r["radius"]
    lat = r["cdir"] * (r["radius"] - radius)
    return s, lat


def local_coordinates(lanes: LaneTable, idx, px, py):
    """World position -> (longitudinal, lateral) on lane ``idx`` (``lane.local_coordinates``)."""
    r = lanes.row(idx)
    s_lin, lat_lin = linear_local(r, px, py)
    lat_lin = jnp.where(r["kind"] == SINE, lat_lin - sine_offset(r, s_lin), lat_lin)
    s_cir, lat_cir = _circular_local(r, px, py)
    circ = r["kind"] == CIRCULAR
    return jnp.where(circ, s_cir, s_lin), jnp.where(circ, lat_cir, lat_lin)


def position(lanes: LaneTable, idx, s, lat):
    """(longitudinal, lateral) on lane ``idx`` -> world position (``lane.position``)."""
    r = lanes.row(idx)
    lat_lin = jnp.where(r["kind"] == SINE, lat + sine_offset(r, s), lat)
    x_lin = r["start_x"] + s * r["dir_x"] + lat_lin * r["lat_x"]
    y_lin = r["start_y"] + s * r["dir_y"] + lat_lin * r["lat_y"]
    phi = r["cdir"] * s / jnp.where(r["radius"] == 0, 1.0, r["radius"]) + r["start_phase"]
    rad = r["radius"] - lat * r["cdir"]
    sin_phi, cos_phi = trig.sin_cos(phi)
    x_cir = r["center_x"] + rad * cos_phi
    y_cir = r["center_y"] + rad * sin_phi
    circ = r["kind"] == CIRCULAR
    return jnp.where(circ, x_cir, x_lin), jnp.where(circ, y_cir, y_lin)


def heading_at(lanes: LaneTable, idx, s):
    """Lane heading at longitudinal coordinate ``s`` (``lane.heading_at``). Only the lane families the road has
    are evaluated (a straight road costs no trigonometry), from the columns they read."""
    sine = lanes.sine_rows.size > 0
    circular = lanes.circular_rows.size > 0
    names = ["heading"] + (["amplitude", "pulsation", "phase"] if sine else [])
    names += ["start_phase", "cdir", "radius"] if circular else []
    r = lanes.columns(idx, names)
    kind = jnp.asarray(lanes.kind)[idx]
    h = r["heading"]
    if sine:
        sine_term = trig.arctan(r["amplitude"] * r["pulsation"] * trig.cos(r["pulsation"] * s + r["phase"]))
        h = jnp.where(kind == SINE, r["heading"] + sine_term, h)
    if circular:
        radius = jnp.where(r["radius"] == 0, 1.0, r["radius"])
        h_cir = r["cdir"] * s / radius + r["start_phase"] + jnp.pi / 2 * r["cdir"]
        h = jnp.where(kind == CIRCULAR, h_cir, h)
    return h


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
