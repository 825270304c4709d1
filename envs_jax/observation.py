"""Kinematic observation of the authors' runner (highway-env ``KinematicObservation``).

Configuration used by every experiment: features ``[x, y, vx, vy]``,
``vehicles_count=2``, absolute world coordinates, no normalisation,
``see_behind=True``, obstacles not observed. Agent ``i`` sees itself and the
nearest other vehicle closer than ``PERCEPTION_DISTANCE`` (strictly); the other
row is zero when there is none. The runner flattens the per-agent ``(2, 4)``
arrays into ``(2, 8)``: row ``i = [x_i, y_i, vx_i, vy_i, x_j, y_j, vx_j, vy_j]``.
Velocities are ``speed * (cos psi, sin psi)`` (no slip angle).
"""

from __future__ import annotations

import jax.numpy as jnp

from envs_jax import trig

PERCEPTION_DISTANCE = 5.0 * 40.0  # 5 * Vehicle.MAX_SPEED


def kinematics(x, y, heading, speed):
    """Per-vehicle feature rows ``[N, 4] = [x, y, vx, vy]``."""
    sin_h, cos_h = trig.sin_cos(heading)
    return jnp.stack([x, y, speed * cos_h, speed * sin_h], axis=-1)


def observe(x, y, heading, speed, perception_distance=PERCEPTION_DISTANCE):
    """Observation ``[N, 8]`` for N vehicles (N = 2 here): own features, then the nearest other's.

    With more than two vehicles the nearest one (Euclidean, first on ties) fills
    the second slot; highway-env sorts by lane distance, which coincides for two.
    """
    feats = kinematics(x, y, heading, speed)  # [N, 4]
    n = feats.shape[0]
    dx = x[None, :] - x[:, None]
    dy = y[None, :] - y[:, None]
    dist = jnp.sqrt(dx * dx + dy * dy)
    dist = jnp.where(jnp.eye(n, dtype=bool), jnp.inf, dist)
    nearest = jnp.argmin(dist, axis=1)
    visible = jnp.take_along_axis(dist, nearest[:, None], axis=1)[:, 0] < perception_distance
    other = jnp.where(visible[:, None], feats[nearest], 0.0)
    return jnp.concatenate([feats, other], axis=-1)
