"""highway-env's ``KinematicObservation`` and ``MultiAgentObservation`` for V vehicle slots.

One observation per controlled vehicle, ``[vehicles_count, len(features)]`` float32:
row 0 is the observer (always in absolute coordinates, with its destination
direction), the next rows are ``road.close_objects_to(observer, PERCEPTION_DISTANCE,
vehicles_count - 1, see_behind, sort=order == "sorted")``: alive vehicles (list
order) then obstacles, closer than the perception distance, those behind dropped
unless ``see_behind`` (obstacles behind always dropped), sorted stably by
``|observer.lane_distance_to(v)|``. Their ``x, y, vx, vy`` are relative to the
observer unless ``absolute``. With ``normalize``, each feature of
``features_range`` is mapped linearly from its range to [-1, 1] (then clipped to it
with ``clip``); missing rows are zeros; ``order="shuffled"`` permutes rows 1.. with
the step's key (highway-env uses its own generator there).

The default ``features_range`` is highway-env's: ``x`` +-5 MAX_SPEED, ``y`` +-4 m times
the number of lanes of the observer's road, ``vx, vy`` +-2 MAX_SPEED. (highway-env
fixes the lane count at the first observation; on a single-road network, as in
``highway-v0``, that is the same number.) Obstacles have no heading or lane
offsets: those features are NaN for them, as in highway-env's data frame.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import lanes as L
from envs_jax import trig
from envs_jax import vehicle as Veh
from envs_jax.observation_config import check_features, check_features_range, check_flags, given_fields
from envs_jax.road import Road
from envs_jax.traffic_state import TrafficState

FEATURES = ("presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h", "cos_d", "sin_d",
            "long_off", "lat_off", "ang_off")
PERCEPTION_DISTANCE = 5.0 * Veh.MAX_SPEED
ORDERS = ("sorted", "shuffled")
_COL = {f: i for i, f in enumerate(FEATURES)}
_RELATIVE = ("x", "y", "vx", "vy")


@dataclasses.dataclass(frozen=True)
class KinematicsConfig:
    """The options of ``KinematicObservation`` (highway-env's defaults); static (hashable)."""

    features: tuple = ("presence", "x", "y", "vx", "vy")
    vehicles_count: int = 5
    features_range: Any = None  # tuple of (name, (lo, hi)) pairs, or None for the defaults
    absolute: bool = False
    order: str = "sorted"
    normalize: bool = True
    clip: bool = True
    see_behind: bool = False
    observe_intentions: bool = False
    include_obstacles: bool = True

    @staticmethod
    def from_config(config: dict, where: str = "observation") -> "KinematicsConfig":
        """Validate a highway-env ``{"type": "Kinematics", ...}`` dict (``ValueError`` naming the problem)."""
        out = given_fields(config, KinematicsConfig, "Kinematics", where)
        check_features(out, FEATURES, where)
        if "vehicles_count" in out:
            n = out["vehicles_count"]
            if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
                raise ValueError(f"{where}: vehicles_count must be an integer >= 1, got {n!r}")
            out["vehicles_count"] = int(n)
        if "order" in out and out["order"] not in ORDERS:
            raise ValueError(f"{where}: order must be one of {list(ORDERS)}, got {out['order']!r}")
        check_flags(out, ("absolute", "normalize", "clip", "see_behind", "observe_intentions", "include_obstacles"),
                    where)
        check_features_range(out, where)
        return KinematicsConfig(**out)

    @property
    def shape(self) -> tuple:
        return (self.vehicles_count, len(self.features))


def _lmap(v, lo, hi):
    """``utils.lmap(v, [lo, hi], [-1, 1])`` with highway-env's operation order."""
    return -1.0 + (v - lo) * 2.0 / (hi - lo)


def feature_table(road: Road, st: TrafficState, obstacles):
    """``to_dict()`` of every road object (slots then obstacles): ``[N, 13]`` in ``FEATURES`` order."""
    lanes = road.lanes
    s, c = trig.sin_cos(st.heading)
    vx, vy = st.speed * c, st.speed * s
    long, lat = L.local_coordinates(lanes, st.lane, st.x, st.y)
    ang = L.wrap_to_pi(st.heading - L.heading_at(lanes, st.lane, long))
    # destination: end of the last route lane (lane id 0 when the route leaves it open)
    has_route = st.route_ptr < st.route_len
    last = jnp.clip(st.route_len - 1, 0, st.route_roads.shape[-1] - 1)
    last_road = jnp.maximum(jnp.take_along_axis(st.route_roads, last[:, None], axis=-1)[:, 0], 0)
    last_id = jnp.maximum(jnp.take_along_axis(st.route_ids, last[:, None], axis=-1)[:, 0], 0)
    dest_lane = jnp.asarray(road.road_lanes)[last_road, last_id]
    dx_, dy_ = L.position(lanes, dest_lane, lanes.col("length")[dest_lane], jnp.zeros_like(st.x))
    dx_ = jnp.where(has_route, dx_, st.x) - st.x
    dy_ = jnp.where(has_route, dy_, st.y) - st.y
    moved = (dx_ != 0) | (dy_ != 0)
    norm = jnp.where(moved, jnp.sqrt(dx_ * dx_ + dy_ * dy_), 1.0)
    cos_d = jnp.where(moved, dx_ / norm, 0.0)
    sin_d = jnp.where(moved, dy_ / norm, 0.0)
    one = jnp.ones_like(st.x)
    rows = jnp.stack([one, st.x, st.y, vx, vy, st.heading, c, s, cos_d, sin_d, long, lat, ang], axis=-1)
    if obstacles is None or obstacles.shape[0] == 0:
        return rows
    ob = jnp.asarray(obstacles, st.x.dtype)
    zero = jnp.zeros_like(ob[:, 0])
    nan = jnp.full_like(ob[:, 0], jnp.nan)
    ob_sin, ob_cos = trig.sin_cos(ob[:, 2])
    orows = jnp.stack([zero + 1, ob[:, 0], ob[:, 1], zero, zero, nan, ob_cos, ob_sin,
                       zero, zero, nan, nan, nan], axis=-1)
    return jnp.concatenate([rows, orows], axis=0)


def observe_one(cfg: KinematicsConfig, road: Road, st: TrafficState, table, observer, obstacles, key,
                range_lanes=None):
    """Observation of the vehicle in slot ``observer`` (traced int): ``[vehicles_count, F]``.

    ``range_lanes``: lane count of the default ``y`` range (None: the observer's current road)."""
    lanes = road.lanes
    n_slots = st.x.shape[0]
    n_obj = table.shape[0]
    is_vehicle = jnp.arange(n_obj) < n_slots
    px, py = table[:, 1], table[:, 2]
    ox, oy = st.x[observer], st.y[observer]
    s_all, _ = L.local_coordinates(lanes, st.lane[observer], px, py)
    lane_distance = s_all - s_all[observer]
    dx, dy = px - ox, py - oy
    dist = jnp.sqrt(dx * dx + dy * dy)
    present = jnp.concatenate([st.alive, jnp.ones(n_obj - n_slots, bool)])
    ahead = -2 * Veh.LENGTH < lane_distance
    keep = present & (dist < PERCEPTION_DISTANCE) & (jnp.arange(n_obj) != observer)
    keep = keep & jnp.where(is_vehicle, cfg.see_behind | ahead, ahead & cfg.include_obstacles)
    if cfg.order == "sorted":
        key_sort = jnp.where(keep, jnp.abs(lane_distance), jnp.inf)
        rank = jnp.argsort(key_sort, stable=True)
    else:
        rank = jnp.argsort(~keep, stable=True)
    m = cfg.vehicles_count - 1
    chosen = rank[:m]
    chosen_ok = keep[chosen]
    ego_row = table[observer]
    others = table[chosen]
    if not cfg.absolute:
        rel = np.zeros(len(FEATURES), bool)
        rel[[_COL[f] for f in _RELATIVE]] = True
        others = jnp.where(jnp.asarray(rel), others - ego_row, others)
    if not cfg.observe_intentions:
        others = others.at[:, _COL["cos_d"]].set(0.0).at[:, _COL["sin_d"]].set(0.0)
    rows = jnp.concatenate([ego_row[None], others], axis=0)
    cols = [_COL[f] for f in cfg.features]
    rows = rows[:, np.asarray(cols, np.int32)]
    if cfg.normalize:
        rng = (default_ranges(road, st.lane[observer], range_lanes) if cfg.features_range is None
               else dict(cfg.features_range))
        for j, f in enumerate(cfg.features):
            if f in rng:
                lo, hi = rng[f]
                v = _lmap(rows[:, j], lo, hi)
                rows = rows.at[:, j].set(jnp.clip(v, -1, 1) if cfg.clip else v)
    filled = jnp.concatenate([jnp.ones((1,), bool), chosen_ok])
    obs = jnp.where(filled[:, None], rows, 0.0)
    if cfg.order == "shuffled":
        obs = obs.at[1:].set(jax.random.permutation(key, obs[1:], axis=0))
    return obs.astype(jnp.float32)


def default_ranges(road: Road, lane, n_lanes=None):
    """highway-env's default ``features_range`` for an observer on ``lane`` (or with ``n_lanes`` side lanes)."""
    if n_lanes is None:
        n_lanes = jnp.asarray(road.road_num_lanes)[jnp.asarray(road.lane_road)[lane]]
    y = L.DEFAULT_WIDTH * n_lanes
    return {"x": (-5.0 * Veh.MAX_SPEED, 5.0 * Veh.MAX_SPEED), "y": (-y, y),
            "vx": (-2 * Veh.MAX_SPEED, 2 * Veh.MAX_SPEED), "vy": (-2 * Veh.MAX_SPEED, 2 * Veh.MAX_SPEED)}


def observe(cfg: KinematicsConfig, road: Road, st: TrafficState, observers, obstacles=None, key=None,
            range_lanes=None):
    """``MultiAgentObservation``: ``[K, vehicles_count, F]`` float32, one per slot of ``observers``.

    ``range_lanes``: optional static ``[K]`` lane counts of the default ``y`` range per observer
    (highway-env fixes it at an observer's first observation: the road it starts on)."""
    table = feature_table(road, st, obstacles)
    observers = jnp.asarray(np.asarray(observers, np.int32))
    key = jax.random.key(0) if key is None else key
    keys = jax.random.split(key, observers.shape[0])
    if range_lanes is None:
        return jax.vmap(lambda o, k: observe_one(cfg, road, st, table, o, obstacles, k))(observers, keys)
    n = jnp.asarray(np.asarray(range_lanes, np.int32))
    return jax.vmap(lambda o, k, m: observe_one(cfg, road, st, table, o, obstacles, k, m))(observers, keys, n)
