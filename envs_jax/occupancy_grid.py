"""highway-env's ``OccupancyGridObservation`` for V vehicle slots (one grid per controlled vehicle).

A grid of ``floor((max - min) / step)`` cells per axis around the observer, one layer
per feature, ``[F, nx, ny]`` float32. Cell ``(i, j)`` of a point at offset ``p`` from
the observer (rotated into the observer's frame with ``align_to_vehicle_axes``) is
``floor((p - grid_min) / grid_step)``.

* A vehicle feature (``presence``, ``x``, ``y``, ``vx``, ``vy``, ``heading``, ...: the
  columns of ``Vehicle.to_dict(observer)``, ``x, y, vx, vy`` relative to the observer)
  is written at each alive vehicle's cell, the observer included; where several
  vehicles share a cell, the first in list order wins (highway-env writes them in
  reverse list order). ``features_range`` maps a feature from its range to [-1, 1];
  the default maps ``vx, vy`` from +-2 MAX_SPEED.
* ``on_road`` marks the cells of the lanes' centre lines: on every lane, 67 waypoints
  from 100 m behind to 100 m ahead of the observer's longitudinal coordinate on that
  lane, spaced by the smaller grid step and clipped to the lane
  (``fill_road_layer_by_lanes``, with numpy ``arange``'s arithmetic).

Empty cells are 0; with ``clip`` every value is clipped to [-1, 1]. Obstacles are not
drawn (highway-env reads ``road.vehicles`` only).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import lanes as L
from envs_jax import trig
from envs_jax import vehicle as Veh
from envs_jax.kinematic_obs import FEATURES as VEHICLE_FEATURES
from envs_jax.kinematic_obs import feature_table
from envs_jax.observation_config import check_features, check_features_range, check_flags, given_fields
from envs_jax.road import Road
from envs_jax.traffic_state import TrafficState

FEATURES = VEHICLE_FEATURES + ("on_road",)
_COL = {f: i for i, f in enumerate(VEHICLE_FEATURES)}
_RELATIVE = ("x", "y", "vx", "vy")
LANE_PERCEPTION_DISTANCE = 100.0  # fill_road_layer_by_lanes: lanes drawn +- this far [m]


@dataclasses.dataclass(frozen=True)
class OccupancyGridConfig:
    """The options of ``OccupancyGridObservation`` (highway-env's class defaults); static (hashable)."""

    features: tuple = ("presence", "vx", "vy", "on_road")
    grid_size: tuple = ((-27.5, 27.5), (-27.5, 27.5))
    grid_step: tuple = (5.0, 5.0)
    features_range: Any = None  # tuple of (name, (lo, hi)) pairs, or None for the default (vx, vy)
    absolute: bool = False
    align_to_vehicle_axes: bool = False
    clip: bool = True
    as_image: bool = False

    @staticmethod
    def from_config(config: dict, where: str = "observation") -> "OccupancyGridConfig":
        """Validate a highway-env ``{"type": "OccupancyGrid", ...}`` dict (``ValueError`` naming the problem)."""
        out = given_fields(config, OccupancyGridConfig, "OccupancyGrid", where, label="OccupancyGrid ")
        check_features(out, FEATURES, where, label="OccupancyGrid ")
        if "grid_size" in out:
            gs = np.asarray(out["grid_size"], dtype=np.float64)
            if gs.shape != (2, 2) or not np.all(np.isfinite(gs)) or not np.all(gs[:, 1] > gs[:, 0]):
                raise ValueError(f"{where}: grid_size must be [[x_min, x_max], [y_min, y_max]] with min < max, "
                                 f"got {out['grid_size']!r}")
            out["grid_size"] = tuple(tuple(float(v) for v in row) for row in gs)
        if "grid_step" in out:
            st = np.asarray(out["grid_step"], dtype=np.float64)
            if st.shape != (2,) or not np.all(np.isfinite(st)) or not np.all(st > 0):
                raise ValueError(f"{where}: grid_step must be [step_x, step_y] with steps > 0, "
                                 f"got {out['grid_step']!r}")
            out["grid_step"] = tuple(float(v) for v in st)
        check_flags(out, ("absolute", "align_to_vehicle_axes", "clip", "as_image"), where)
        if out.get("absolute"):
            raise ValueError(f"{where}: OccupancyGrid absolute=True is not supported (highway-env raises "
                             f"NotImplementedError for it); use absolute=False")
        if out.get("as_image"):
            raise ValueError(f"{where}: OccupancyGrid as_image=True is not supported; use as_image=False "
                             f"(values in [-1, 1])")
        check_features_range(out, where)
        cfg = OccupancyGridConfig(**out)
        if min(cfg.shape[1:]) < 1:
            raise ValueError(f"{where}: grid_size / grid_step give an empty grid {cfg.shape[1:]}")
        return cfg

    @property
    def cells(self) -> tuple:
        size = np.asarray(self.grid_size, np.float64)
        return tuple(int(v) for v in np.floor((size[:, 1] - size[:, 0]) / np.asarray(self.grid_step, np.float64)))

    @property
    def shape(self) -> tuple:
        return (len(self.features),) + self.cells

    def ranges(self) -> dict:
        if self.features_range is None:
            return {"vx": (-2 * Veh.MAX_SPEED, 2 * Veh.MAX_SPEED), "vy": (-2 * Veh.MAX_SPEED, 2 * Veh.MAX_SPEED)}
        return dict(self.features_range)


def _lmap(v, x, y):
    """``utils.lmap(v, x, y)``."""
    return y[0] + (v - x[0]) * (y[1] - y[0]) / (x[1] - x[0])


def _split(a):
    """Dekker's split of ``a`` into a high and a low half (``a = hi + lo`` exactly)."""
    factor = 134217729.0 if a.dtype == jnp.float64 else 4097.0  # 2^ceil(p/2) + 1
    t = factor * a
    hi = t - (t - a)
    return hi, a - hi


def fma(a, b, c):
    """``a * b + c`` rounded once, from error-free transformations (XLA has no fused multiply-add op).

    numpy's 2 x 2 ``matmul`` evaluates ``M @ p`` as ``fma(M[r, 0], p[0], M[r, 1] * p[1])``;
    reproducing it keeps the grid cells of points on a cell boundary (a vehicle on its
    lane's centre line sits on one) identical to highway-env's.
    """
    a, b, c = jnp.broadcast_arrays(a, b, c)
    p = a * b
    ah, al = _split(a)
    bh, bl = _split(b)
    e = ((ah * bh - p) + ah * bl + al * bh) + al * bl  # p + e == a * b exactly
    s = p + c
    bv = s - p
    t = (p - (s - bv)) + (c - bv)  # s + t == p + c exactly
    return s + (t + e)


def _cell(cfg: OccupancyGridConfig, ox, oy, heading, dx, dy):
    """``pos_to_index`` of offsets ``(dx, dy)`` from the observer: integer cells ``(i, j)`` and a validity mask."""
    if cfg.align_to_vehicle_axes:
        s, c = trig.sin_cos(heading)
        dx, dy = fma(c, dx, s * dy), fma(-s, dx, c * dy)
    (x0, _), (y0, _) = cfg.grid_size
    i = jnp.floor((dx - x0) / cfg.grid_step[0])
    j = jnp.floor((dy - y0) / cfg.grid_step[1])
    nx, ny = cfg.cells
    ok = (0 <= i) & (i < nx) & (0 <= j) & (j < ny)
    return jnp.clip(i, 0, nx - 1).astype(jnp.int32), jnp.clip(j, 0, ny - 1).astype(jnp.int32), ok


def _waypoint_count(spacing: float) -> int:
    """Length of ``np.arange(o - D, o + D, spacing)`` (the same for every origin ``o`` up to round-off)."""
    return int(math.ceil(2 * LANE_PERCEPTION_DISTANCE / spacing))


def road_layer(cfg: OccupancyGridConfig, road: Road, ox, oy, heading):
    """``fill_road_layer_by_lanes``: ``[nx, ny]`` with 1 on the cells of the lane centre lines, NaN elsewhere."""
    lanes = road.lanes
    n_lanes = lanes.size
    idx = jnp.arange(n_lanes)
    origin, _ = L.local_coordinates(lanes, idx, ox, oy)  # [L]
    spacing = float(min(cfg.grid_step))
    start = origin - LANE_PERCEPTION_DISTANCE
    delta = (start + spacing) - start  # numpy arange fills start + i * (second - first)
    k = jnp.arange(_waypoint_count(spacing), dtype=origin.dtype)
    w = start[:, None] + k[None, :] * delta[:, None]  # [L, W]
    w = jnp.clip(w, 0, lanes.col("length")[:, None])
    lane = jnp.broadcast_to(idx[:, None], w.shape)
    px, py = L.position(lanes, lane, w, jnp.zeros_like(w))
    i, j, ok = _cell(cfg, ox, oy, heading, px - ox, py - oy)
    nx, ny = cfg.cells
    flat = jnp.where(ok, i * ny + j, nx * ny).reshape(-1)
    hit = jnp.zeros(nx * ny + 1, bool).at[flat].set(True)[: nx * ny]
    return jnp.where(hit.reshape(nx, ny), 1.0, jnp.nan)


def observe_one(cfg: OccupancyGridConfig, road: Road, st: TrafficState, table, observer):
    """The grid of the vehicle in slot ``observer`` (traced int): ``[F, nx, ny]`` float32."""
    n_slots = st.x.shape[0]
    nx, ny = cfg.cells
    ox, oy, heading = st.x[observer], st.y[observer], st.heading[observer]
    rows = table[:n_slots]
    rel = np.zeros(len(VEHICLE_FEATURES), bool)
    rel[[_COL[f] for f in _RELATIVE]] = True
    rows = jnp.where(jnp.asarray(rel), rows - rows[observer], rows)  # to_dict(observer)
    ranges = cfg.ranges()
    for f, rng in ranges.items():
        if f in _COL:
            rows = rows.at[:, _COL[f]].set(_lmap(rows[:, _COL[f]], rng, (-1.0, 1.0)))
    dx, dy = rows[:, _COL["x"]], rows[:, _COL["y"]]
    if "x" in ranges:  # highway-env recovers the unnormalised offsets for the cell index
        dx = _lmap(dx, (-1.0, 1.0), ranges["x"])
    if "y" in ranges:
        dy = _lmap(dy, (-1.0, 1.0), ranges["y"])
    i, j, ok = _cell(cfg, ox, oy, heading, dx, dy)
    ok = ok & st.alive
    slot = jnp.arange(n_slots, dtype=jnp.int32)
    flat = jnp.where(ok, i * ny + j, nx * ny)
    winner = jnp.full(nx * ny + 1, n_slots, jnp.int32).at[flat].min(slot)[: nx * ny]  # first in list order
    occupied = (winner < n_slots).reshape(nx, ny)
    winner = jnp.minimum(winner, n_slots - 1).reshape(nx, ny)
    layers = []
    for f in cfg.features:
        if f == "on_road":
            layers.append(road_layer(cfg, road, ox, oy, heading))
        else:
            layers.append(jnp.where(occupied, rows[winner, _COL[f]], jnp.nan))
    grid = jnp.stack(layers)
    if cfg.clip:
        grid = jnp.clip(grid, -1, 1)
    return jnp.nan_to_num(grid).astype(jnp.float32)


def observe(cfg: OccupancyGridConfig, road: Road, st: TrafficState, observers):
    """``MultiAgentObservation`` of occupancy grids: ``[K, F, nx, ny]`` float32, one per slot of ``observers``."""
    table = feature_table(road, st, None)
    observers = jnp.asarray(np.asarray(observers, np.int32))
    return jax.vmap(lambda o: observe_one(cfg, road, st, table, o))(observers)
