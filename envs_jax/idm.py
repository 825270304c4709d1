"""The Intelligent Driver Model of highway-env's ``IDMVehicle`` (``vehicle/behavior.py``).

:class:`IDMParams` holds the driver constants (highway-env's class attributes as
defaults); they live in the environment's params pytree, so a user can change or
randomise them per environment under ``vmap``. The exponent ``delta`` is also per
vehicle (``randomize_behavior`` draws it in ``delta_range``), so it is an argument of
the functions here rather than read from the params.

Every function acts on scalars or arrays that broadcast together, branch-free.
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from flax import struct

from envs_jax.vehicle import LENGTH, not_zero


@struct.dataclass
class IDMParams:
    """IDM and MOBIL constants (``IDMVehicle``'s class attributes)."""

    acc_max: float = 6.0  # ACC_MAX: clip of the commanded acceleration [m/s^2]
    comfort_acc_max: float = 3.0  # COMFORT_ACC_MAX [m/s^2]
    comfort_acc_min: float = -5.0  # COMFORT_ACC_MIN [m/s^2]
    distance_wanted: float = 5.0 + LENGTH  # DISTANCE_WANTED: jam distance [m]
    time_wanted: float = 1.5  # TIME_WANTED: desired time gap [s]
    delta: float = 4.0  # DELTA: exponent of the free-road term (vehicles not randomised)
    delta_range: Any = (3.5, 4.5)  # DELTA_RANGE of randomize_behavior
    politeness: float = 0.0  # POLITENESS in [0, 1]
    lane_change_min_acc_gain: float = 0.2  # LANE_CHANGE_MIN_ACC_GAIN [m/s^2]
    lane_change_max_braking_imposed: float = 2.0  # LANE_CHANGE_MAX_BRAKING_IMPOSED [m/s^2]
    lane_change_delay: float = 1.0  # LANE_CHANGE_DELAY [s]


def velocity_gap(speed_e, cos_e, sin_e, speed_f, cos_f, sin_f):
    """``dv = (v_ego - v_front) . direction_ego`` with ``velocity = speed * (cos, sin)`` (no slip), from the
    headings' cosines and sines (computed once per vehicle by the caller, not once per pair)."""
    dvx = speed_e * cos_e - speed_f * cos_f
    dvy = speed_e * sin_e - speed_f * sin_f
    return dvx * cos_e + dvy * sin_e


def desired_gap(speed_e, dv, p: IDMParams):
    """``desired_gap``: ``d0 + v tau + v dv / (2 sqrt(ab))``, ``ab = -a_max b_min`` (projected ``dv``)."""
    ab = -p.comfort_acc_max * p.comfort_acc_min
    return p.distance_wanted + speed_e * p.time_wanted + speed_e * dv / (2 * jnp.sqrt(ab))


def free_acceleration(speed_e, target_speed_e, speed_limit_e, delta, p: IDMParams):
    """Free-road term ``a_max (1 - (max(v, 0) / |not_zero(v*)|) ** delta)``, ``v*`` clipped to
    ``[0, speed limit of the ego's lane]``."""
    target = jnp.clip(target_speed_e, 0, speed_limit_e)
    return p.comfort_acc_max * (1 - jnp.power(jnp.maximum(speed_e, 0) / jnp.abs(not_zero(target)), delta))


def interaction(free, speed_e, has_front, d, dv, p: IDMParams):
    """``IDMVehicle.acceleration(ego, front)`` from its :func:`free_acceleration` term ``free``: minus
    ``a_max (desired gap / d)^2`` with a front.

    ``d`` is the lane-longitudinal gap ``ego.lane_distance_to(front)`` (measured on the
    ego's own lane), ``dv`` the :func:`velocity_gap`; both are ignored when
    ``has_front`` is false. ``free``'s ``delta`` and ``p`` are those of the vehicle that *computes*
    the acceleration (in MOBIL, the deciding vehicle, whoever the ego is).
    """
    ratio = desired_gap(speed_e, dv, p) / not_zero(jnp.where(has_front, d, 1.0))
    return jnp.where(has_front, free - p.comfort_acc_max * (ratio * ratio), free)
