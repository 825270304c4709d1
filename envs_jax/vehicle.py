"""Vehicle dynamics and highway-env's low-level controllers.

* :func:`bicycle_step` - ``Vehicle.step``: kinematic bicycle with slip angle,
  explicit Euler, speed guards, crashed-vehicle braking, delayed impact.
* :func:`steering_control`, :func:`speed_control` - ``ControlledVehicle``'s
  cascaded lateral controller and proportional speed controller.
* :func:`meta_action` - ``MDPVehicle.act``: LANE_LEFT / IDLE / LANE_RIGHT /
  FASTER / SLOWER on the target lane and target-speed index.
* :func:`continuous_action` - ``ContinuousAction``: [-1, 1] -> acceleration and steering.

All functions act on one vehicle (scalars); the environment ``vmap``s them
over vehicles.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from envs_jax import trig

LENGTH = 5.0
WIDTH = 2.0
MAX_SPEED = 40.0
MIN_SPEED = -40.0

TAU_ACC = 0.6
TAU_HEADING = 0.2
TAU_LATERAL = 0.6
TAU_PURSUIT = 0.5 * TAU_HEADING
KP_A = 1 / TAU_ACC
KP_HEADING = 1 / TAU_HEADING
KP_LATERAL = 1 / TAU_LATERAL
MAX_STEERING_ANGLE = jnp.pi / 3

LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER = 0, 1, 2, 3, 4
ACTION_NAMES = ("LANE_LEFT", "IDLE", "LANE_RIGHT", "FASTER", "SLOWER")


def not_zero(x, eps=1e-2):
    """``utils.not_zero``: keep |x| >= eps, with the sign of x (0 -> +eps)."""
    return jnp.where(jnp.abs(x) > eps, x, jnp.where(x >= 0, eps, -eps))


def clip_actions(speed, steering, acceleration, crashed):
    """``Vehicle.clip_actions``: a crashed car brakes to a stop; speed kept in [-40, 40].

    Returns the (possibly modified) stored action; highway-env mutates the
    stored action dict, so a held continuous action keeps the clipped value.
    """
    steering = jnp.where(crashed, 0.0, steering)
    acceleration = jnp.where(crashed, -1.0 * speed, acceleration)
    acceleration = jnp.where(speed > MAX_SPEED, jnp.minimum(acceleration, 1.0 * (MAX_SPEED - speed)),
                             jnp.where(speed < MIN_SPEED, jnp.maximum(acceleration, 1.0 * (MIN_SPEED - speed)),
                                       acceleration))
    return steering, acceleration


def bicycle_step(x, y, heading, speed, steering, acceleration, crashed, impact_x, impact_y, has_impact, dt):
    """``Vehicle.step(dt)`` without the lane update.

    beta = arctan(tan(delta) / 2); p += v [cos(psi + beta), sin(psi + beta)] dt;
    a pending impact is added (and latches ``crashed``); psi += v sin(beta) / (L/2) dt;
    v += a dt. Returns the new kinematic state and the clipped stored action.
    """
    steering, acceleration = clip_actions(speed, steering, acceleration, crashed)
    beta = trig.arctan(0.5 * trig.tan(steering))
    sin_hb, cos_hb = trig.sin_cos(heading + beta)
    x = x + speed * cos_hb * dt
    y = y + speed * sin_hb * dt
    x = jnp.where(has_impact, x + impact_x, x)
    y = jnp.where(has_impact, y + impact_y, y)
    crashed = crashed | has_impact
    heading = heading + speed * trig.sin(beta) / (LENGTH / 2) * dt
    speed = speed + acceleration * dt
    return x, y, heading, speed, crashed, steering, acceleration


def below_half_pi(dtype) -> float:
    """Largest value of ``dtype`` not above the true pi/2 (float64: pi/2 itself)."""
    dtype = np.dtype(dtype)
    half_pi = dtype.type(np.pi / 2)  # float64's pi/2 is already just below the true value
    if float(half_pi) > np.pi / 2:
        half_pi = np.nextafter(half_pi, dtype.type(0))
    return float(half_pi)


def speed_control(target_speed, speed):
    """``ControlledVehicle.speed_control``: a = KP_A (v* - v)."""
    return KP_A * (target_speed - speed)


def steering_control(lanes: L.LaneTable, target_lane, s, lat, heading, speed):
    """``ControlledVehicle.steering_control``: lateral -> heading -> heading-rate -> steering cascade.

    ``s, lat`` are the vehicle's local coordinates on ``target_lane``.
    """
    future_heading = L.heading_at(lanes, target_lane, s + speed * TAU_PURSUIT)
    lateral_speed_command = -KP_LATERAL * lat
    heading_command = trig.arcsin(jnp.clip(lateral_speed_command / not_zero(speed), -1, 1))
    heading_ref = future_heading + jnp.clip(heading_command, -jnp.pi / 4, jnp.pi / 4)
    heading_rate_command = KP_HEADING * L.wrap_to_pi(heading_ref - heading)
    slip_angle = trig.arcsin(jnp.clip(LENGTH / 2 / not_zero(speed) * heading_rate_command, -1, 1))
    # float32 rounds arcsin(+-1) to a value just *beyond* pi/2, whose tan has the wrong sign and
    # would steer full lock the wrong way; keep |slip| strictly below pi/2 (a no-op in float64).
    limit = below_half_pi(slip_angle.dtype)
    slip_angle = jnp.clip(slip_angle, -limit, limit)
    steering = trig.arctan(2 * trig.tan(slip_angle))
    return jnp.clip(steering, -MAX_STEERING_ANGLE, MAX_STEERING_ANGLE)


def speed_to_index(speed, target_speeds):
    """``MDPVehicle.speed_to_index``: nearest index of a uniform speed grid (round half to even)."""
    n = target_speeds.shape[-1]
    x = (speed - target_speeds[0]) / (target_speeds[-1] - target_speeds[0])
    return jnp.clip(jnp.round(x * (n - 1)), 0, n - 1).astype(jnp.int32)


def meta_action(road, action, target_lane, speed_index, x, y, circles, speed, target_speeds):
    """Apply one discrete meta-action (``MDPVehicle.act``) to the target lane and speed index.

    FASTER/SLOWER re-index from the *current* speed (+-1, clipped). LANE_LEFT/RIGHT
    move the target lane id by -+1 on the same road (clipped) and are accepted
    only if the new lane ``is_reachable_from`` the position ``x, y`` (``circles``: its
    ``LL.circle_coords``). Returns
    ``(target_lane, speed_index, target_speed)``.
    """
    n = target_speeds.shape[-1]
    current = speed_to_index(speed, target_speeds)
    new_index = jnp.where(action == FASTER, current + 1, jnp.where(action == SLOWER, current - 1, speed_index))
    new_index = jnp.clip(new_index, 0, n - 1).astype(jnp.int32)
    changes_speed = (action == FASTER) | (action == SLOWER)
    speed_index = jnp.where(changes_speed, new_index, speed_index)

    lane_road = jnp.asarray(road.lane_road)[target_lane]
    lane_id = jnp.asarray(road.lane_id)[target_lane]
    n_lanes = jnp.asarray(road.road_num_lanes)[lane_road]
    delta = jnp.where(action == LANE_RIGHT, 1, jnp.where(action == LANE_LEFT, -1, 0))
    cand_id = jnp.clip(lane_id + delta, 0, n_lanes - 1)
    candidate = jnp.asarray(road.road_lanes)[lane_road, cand_id]
    lane_width = road.lanes.col("width")[candidate]
    lane_length = road.lanes.col("length")[candidate]
    cs, clat = LL.lane_coords(road.lanes, x, y, circles, candidate)
    reachable = ((jnp.abs(clat) <= 2 * lane_width) & (0 <= cs) & (cs < lane_length + L.VEHICLE_LENGTH)
                 & ~jnp.asarray(road.lanes.forbidden)[candidate])
    changes_lane = (action == LANE_LEFT) | (action == LANE_RIGHT)
    target_lane = jnp.where(changes_lane & reachable, candidate, target_lane)
    target_speed = target_speeds[speed_index]
    return target_lane.astype(jnp.int32), speed_index, target_speed


def continuous_action(action, longitudinal: bool, lateral: bool,
                      acceleration_range=(-5.0, 5.0), steering_range=(-jnp.pi / 4, jnp.pi / 4)):
    """``ContinuousAction``: clip to [-1, 1], map linearly to acceleration / steering.

    With ``longitudinal`` only, steering is 0; with ``lateral`` only, acceleration is 0.
    ``action`` has shape ``[longitudinal + lateral]``.
    """
    a = jnp.clip(action, -1.0, 1.0)

    def lmap(v, lo, hi):
        return lo + (v + 1.0) * (hi - lo) / 2.0

    if longitudinal and lateral:
        return lmap(a[0], *acceleration_range), lmap(a[1], *steering_range)
    if longitudinal:
        return lmap(a[0], *acceleration_range), jnp.zeros_like(a[0])
    return jnp.zeros_like(a[0]), lmap(a[0], *steering_range)
