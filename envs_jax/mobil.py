"""MOBIL (``IDMVehicle.mobil``): is a lane change safe and worth it?

Accelerations are evaluated between road objects named by index (list order:
vehicle slots, then obstacles; ``-1`` = none) through an :class:`ObjectTable`,
always with the *deciding* vehicle's IDM constants, as highway-env's
``self.acceleration(ego_vehicle=other, ...)`` does.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from envs_jax import idm


class ObjectTable(NamedTuple):
    """What ``IDMVehicle.acceleration`` reads of any road object (``[N]`` unless noted)."""

    speed: jax.Array
    cos_h: jax.Array  # cosine of the heading
    sin_h: jax.Array  # sine of the heading
    target_speed: jax.Array  # ``getattr(v, "target_speed", 0)``: 0 for plain vehicles
    speed_limit: jax.Array  # speed limit of the object's current lane
    is_vehicle: jax.Array  # obstacles are no ``Vehicle``: as ego they get acceleration 0
    s_own: jax.Array  # [V, N]: s_own[a, b] = longitudinal coordinate of b on vehicle a's current lane


def free_acceleration(objs: ObjectTable, ego, delta, p: idm.IDMParams):
    """The free-road term of ``acceleration(ego_vehicle=objs[ego])`` with the deciding vehicle's ``delta``."""
    e = jnp.clip(ego, 0, objs.speed.shape[0] - 1)
    return idm.free_acceleration(objs.speed[e], objs.target_speed[e], objs.speed_limit[e], delta, p)


def pair_acceleration(objs: ObjectTable, ego, front, delta, p: idm.IDMParams, free=None):
    """``acceleration(ego_vehicle=objs[ego], front_vehicle=objs[front])``; 0 without an ego
    (``ego < 0``) or when the ego is an obstacle; the free-road term without a front (``front < 0``).
    ``free``: the pairs' :func:`free_acceleration` if already computed (it holds the power, the costly part)."""
    n_rows = objs.s_own.shape[0]
    e = jnp.clip(ego, 0, objs.speed.shape[0] - 1)
    er = jnp.clip(ego, 0, n_rows - 1)
    f = jnp.maximum(front, 0)
    d = objs.s_own[er, f] - objs.s_own[er, er]
    dv = idm.velocity_gap(objs.speed[e], objs.cos_h[e], objs.sin_h[e], objs.speed[f], objs.cos_h[f], objs.sin_h[f])
    free = free_acceleration(objs, ego, delta, p) if free is None else free
    acc = idm.interaction(free, objs.speed[e], front >= 0, d, dv, p)
    return jnp.where((ego >= 0) & objs.is_vehicle[e], acc, 0.0)


def mobil(objs: ObjectTable, me, new_preceding, new_following, old_preceding, old_following,
          lane_id, target_id, route_fixes_lane, route_id, delta, p: idm.IDMParams):
    """``IDMVehicle.mobil(lane)`` for the vehicle ``me`` and a candidate lane of id ``lane_id``.

    ``new_*``: its neighbours on the candidate lane, ``old_*`` on its current lane;
    ``target_id``: the id of its current target lane; ``route_fixes_lane``: the head
    of its route names a lane id (``route[0][2] is not None``), ``route_id`` that id.
    """
    ego = jnp.stack(jnp.broadcast_arrays(new_following, new_following, me, me, old_following, old_following))
    front = jnp.stack(jnp.broadcast_arrays(new_preceding, me, new_preceding, old_preceding, me, old_preceding))
    acc = pair_acceleration(objs, ego, front, delta, p)
    return accept(*acc, lane_id, target_id, route_fixes_lane, route_id, p)


def accept(new_following_a, new_following_pred_a, self_pred_a, self_a, old_following_a, old_following_pred_a,
           lane_id, target_id, route_fixes_lane, route_id, p: idm.IDMParams):
    """MOBIL's decision from the six accelerations it compares (``acceleration(ego, front)``):
    new follower behind its preceding / behind me, me behind the new / old preceding,
    old follower behind me / behind the old preceding."""
    unsafe = new_following_pred_a < -p.lane_change_max_braking_imposed
    # a route that fixes the lane: reject the wrong direction or an unsafe braking
    wrong_way = jnp.sign(lane_id - target_id) != jnp.sign(route_id - target_id)
    route_reject = wrong_way | (self_pred_a < -p.lane_change_max_braking_imposed)
    # otherwise: the acceleration advantage for me and (politely) my followers
    jerk = self_pred_a - self_a + p.politeness * (
        new_following_pred_a - new_following_a + old_following_pred_a - old_following_a)
    gain_reject = jerk < p.lane_change_min_acc_gain
    return ~unsafe & jnp.where(route_fixes_lane, ~route_reject, ~gain_reject)
