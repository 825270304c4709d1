"""highway-env's ``BicycleVehicle`` (``vehicle/dynamics.py``): a dynamical bicycle with linear tyre forces.

The state of one vehicle is the kinematic ``x, y, heading, speed`` plus the body-frame
``lateral_speed`` and ``yaw_rate``. One ``BicycleVehicle.step(dt)``:

1. ``clip_actions``: ``Vehicle.clip_actions`` (a crashed vehicle's stored command becomes
   steering 0, acceleration ``-speed``; beyond +-40 m/s the acceleration is bounded back),
   the steering clipped to +-pi/2 and the yaw rate to +-2 pi rad/s (both stored);
2. one fourth-order Runge-Kutta step of :func:`derivative` with the command held.

:func:`derivative` is Rajamani's lateral model (see docs/scenarios.md, "intersection-v1"):
slip angles ``theta_f,r = arctan2(v_lat +- a r, v)``, tyre forces ``2 C (delta - theta)``
(no rear steering), and below 1 m/s the forces replaced by damping of the lateral speed
and yaw rate, as highway-env does; the position moves with the body velocity
``R(heading) [speed, lateral_speed]``. Unlike ``Vehicle.step``, nothing here applies a
collision impact: a ``BicycleVehicle`` is only marked crashed by an overlap.

All functions are elementwise (scalars or arrays of vehicles), branch-free.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import trig
from envs_jax import vehicle as Veh

MASS = 1.0  # [kg]
LENGTH_A = Veh.LENGTH / 2  # [m] centre of mass to front axle
LENGTH_B = Veh.LENGTH / 2  # [m] centre of mass to rear axle
INERTIA_Z = 1 / 12 * MASS * (Veh.LENGTH ** 2 + Veh.WIDTH ** 2)  # [kg m^2]
FRICTION_FRONT = 15.0 * MASS  # [N] cornering stiffness
FRICTION_REAR = 15.0 * MASS  # [N]
MAX_ANGULAR_SPEED = 2 * np.pi  # [rad/s]
MAX_STEERING = np.pi / 2  # clip required by the linearisation
LOW_SPEED = 1.0  # [m/s] below it the tyre forces become damping


def derivative(heading, speed, lateral_speed, yaw_rate, steering, acceleration):
    """``derivative_func``: ``(dx, dy, dheading, dspeed, dlateral_speed, dyaw_rate)``."""
    theta_vf = trig.arctan2(lateral_speed + LENGTH_A * yaw_rate, speed)
    theta_vr = trig.arctan2(lateral_speed - LENGTH_B * yaw_rate, speed)
    f_yf = 2 * FRICTION_FRONT * (steering - theta_vf)
    f_yr = 2 * FRICTION_REAR * (0 - theta_vr)
    low = jnp.abs(speed) < LOW_SPEED
    f_yf = jnp.where(low, -MASS * lateral_speed - INERTIA_Z / LENGTH_A * yaw_rate, f_yf)
    f_yr = jnp.where(low, -MASS * lateral_speed + INERTIA_Z / LENGTH_A * yaw_rate, f_yr)
    d_lateral_speed = 1 / MASS * (f_yf + f_yr) - yaw_rate * speed
    d_yaw_rate = 1 / INERTIA_Z * (LENGTH_A * f_yf - LENGTH_B * f_yr)
    s, c = trig.sin_cos(heading)
    dx = c * speed + -s * lateral_speed
    dy = s * speed + c * lateral_speed
    return dx, dy, yaw_rate, acceleration + jnp.zeros_like(speed), d_lateral_speed, d_yaw_rate


def clip_actions(speed, yaw_rate, steering, acceleration, crashed):
    """``BicycleVehicle.clip_actions``: ``(yaw_rate, steering, acceleration)`` as stored after it."""
    steering, acceleration = Veh.clip_actions(speed, steering, acceleration, crashed)
    steering = jnp.clip(steering, -MAX_STEERING, MAX_STEERING)
    yaw_rate = jnp.clip(yaw_rate, -MAX_ANGULAR_SPEED, MAX_ANGULAR_SPEED)
    return yaw_rate, steering, acceleration


def rk4(x, y, heading, speed, lateral_speed, yaw_rate, steering, acceleration, dt):
    """``rk4(derivative_func, state, dt)`` with the command held: the six new state components."""
    state = (x, y, heading, speed, lateral_speed, yaw_rate)

    def f(s):
        return derivative(s[2], s[3], s[4], s[5], steering, acceleration)

    def shift(s, d, h):
        return tuple(a + b * h for a, b in zip(s, d))

    f1 = f(state)
    f2 = f(shift(state, f1, dt / 2))
    f3 = f(shift(state, f2, dt / 2))
    f4 = f(shift(state, f3, dt))
    return tuple(s + (dt / 6) * (a + 2 * b + 2 * c + d) for s, a, b, c, d in zip(state, f1, f2, f3, f4))


def step(x, y, heading, speed, lateral_speed, yaw_rate, steering, acceleration, crashed, dt):
    """``BicycleVehicle.step(dt)`` without the lane update.

    Returns ``(x, y, heading, speed, lateral_speed, yaw_rate, steering, acceleration)``: the new
    state and the stored command after ``clip_actions``.
    """
    yaw_rate, steering, acceleration = clip_actions(speed, yaw_rate, steering, acceleration, crashed)
    new = rk4(x, y, heading, speed, lateral_speed, yaw_rate, steering, acceleration, dt)
    return new + (steering, acceleration)


def predict_constant_steering(x, y, heading, speed, lateral_speed, yaw_rate, steering, crashed, dt, n: int):
    """``Vehicle.predict_trajectory_constant_speed`` of a ``BicycleVehicle`` (``prediction_type``
    "constant_steering"): a copy told ``acceleration 0`` and its stored ``steering`` takes ``n`` steps of
    ``dt``; returns its positions and headings after each, ``(x, y, heading)`` with a trailing ``[n]`` axis."""

    def body(carry, _):
        xs, ys, hs, vs, ls, rs, st, ac = carry
        out = step(xs, ys, hs, vs, ls, rs, st, ac, crashed, dt)
        return out, (out[0], out[1], out[2])

    zero = jnp.zeros_like(speed)
    carry = (x, y, heading, speed, lateral_speed, yaw_rate, steering + zero, zero)
    _, (px, py, ph) = jax.lax.scan(body, carry, None, length=n)
    move = lambda a: jnp.moveaxis(a, 0, -1)
    return move(px), move(py), move(ph)
