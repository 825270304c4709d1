"""Queries of every lane at once: a point's local coordinates on each lane of the table, and the all-lane
closest-lane search (the first lane with the least distance-with-heading, highway-env's
``get_closest_lane_index``).

Each lane family is evaluated only on its own rows (a static partition of the table) and the results are
scattered back into table order, so the search costs one pass per family.
"""

from __future__ import annotations

import jax.numpy as jnp

from envs_jax import trig
from envs_jax.lanes import FIELDS, LaneTable, distance_from_coords, float_dtype, linear_local, sine_offset, wrap_to_pi

__all__ = ["local_coordinates_all", "first_argmin", "distance_with_heading_all"]


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
        r = {name: lanes.col(name, rows) for name in FIELDS}
        s, lat = linear_local(r, px, py)
        h = jnp.broadcast_to(r["heading"], s.shape)
        if lanes.sine_rows_in_linear.size:
            sub = lanes.sine_rows_in_linear
            rs = {name: v[sub] for name, v in r.items()}
            s_sin = s[..., sub]
            lat = lat.at[..., sub].add(-sine_offset(rs, s_sin))
            if with_heading:
                h = h.at[..., sub].add(trig.arctan(rs["amplitude"] * rs["pulsation"]
                                                  * trig.cos(rs["pulsation"] * s_sin + rs["phase"])))
        parts_s.append(s)
        parts_lat.append(lat)
        parts_h.append(h)
    if lanes.circular_rows.size:
        rows = lanes.circular_rows
        r = {name: lanes.col(name, rows) for name in FIELDS}
        # atan2 and the radius once per distinct centre (all ring lanes share one).
        centers = jnp.asarray(lanes.circle_centers, dtype=float_dtype())
        dx = px - centers[:, 0]
        dy = py - centers[:, 1]
        phi_c = trig.arctan2(dy, dx)[..., lanes.circle_of_row]
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
    perm = lanes.unpermute
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
