"""``envs_jax.dynamics`` against highway-env's own ``BicycleVehicle`` (``vehicle/dynamics.py``).

Random states cover both tyre regimes (|speed| below and above 1 m/s), speeds beyond the +-40 m/s
guard, yaw rates beyond +-2 pi rad/s and steering beyond +-pi/2 (both clipped), and crashed
vehicles (their stored command rewritten). Under x64 one step, a run of steps and the
constant-steering prediction of the regulation agree with highway-env to rounding.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from highway_env.vehicle.dynamics import BicycleVehicle

from envs_jax import dynamics
from envs_jax.regulation import PREDICTION_TIMES

DT = 1 / 15


def random_states(n, seed=0):
    rng = np.random.default_rng(seed)
    speed = np.concatenate([rng.uniform(-0.99, 0.99, n // 4), rng.uniform(-45, 45, n // 4),
                            rng.uniform(38, 46, n // 4), rng.uniform(1, 12, n - 3 * (n // 4))])
    return dict(x=rng.uniform(-50, 50, n), y=rng.uniform(-50, 50, n), heading=rng.uniform(-4, 4, n), speed=speed,
                lateral_speed=rng.uniform(-3, 3, n), yaw_rate=rng.uniform(-8, 8, n),
                steering=rng.uniform(-2, 2, n), acceleration=rng.uniform(-5, 5, n), crashed=rng.uniform(size=n) < 0.2)


def highway_env_vehicle(s, i):
    v = BicycleVehicle(None, [s["x"][i], s["y"][i]], heading=float(s["heading"][i]), speed=float(s["speed"][i]))
    v.lateral_speed, v.yaw_rate = float(s["lateral_speed"][i]), float(s["yaw_rate"][i])
    v.crashed = bool(s["crashed"][i])
    v.act({"steering": float(s["steering"][i]), "acceleration": float(s["acceleration"][i])})
    return v


def vehicle_row(v):
    return [v.position[0], v.position[1], v.heading, v.speed, v.lateral_speed, v.yaw_rate]


def test_regimes_covered():
    s = random_states(64)
    assert np.sum(np.abs(s["speed"]) < 1) > 5 and np.sum(np.abs(s["speed"]) > 40) > 5
    assert np.sum(np.abs(s["yaw_rate"]) > 2 * np.pi) > 5 and np.sum(np.abs(s["steering"]) > np.pi / 2) > 5
    assert np.sum(s["crashed"]) > 5


@pytest.mark.parametrize("frames, tol", [(1, 1e-12), (20, 1e-8)])
def test_steps_match_highway_env(x64, frames, tol):
    """``frames`` steps of dt = 1/15 s with the command held (and mutated by clip_actions), state and stored
    command after each; over many frames the stiff tyre forces near 1 m/s amplify last-bit differences of
    ``arctan2`` / ``cos`` / ``sin``, hence the looser bound."""
    s = random_states(64)
    f = jax.jit(lambda *a: dynamics.step(*a, DT))
    st = [jnp.asarray(s[k]) for k in ("x", "y", "heading", "speed", "lateral_speed", "yaw_rate", "steering",
                                       "acceleration")]
    crashed = jnp.asarray(s["crashed"])
    vs = [highway_env_vehicle(s, i) for i in range(64)]
    for _ in range(frames):
        st = list(f(*st[:8], crashed))
        for v in vs:
            v.step(DT)
    want = np.array([vehicle_row(v) + [v.action["steering"], v.action["acceleration"]] for v in vs])
    got = np.stack([np.asarray(a) for a in st], axis=1)
    scale = np.maximum(1.0, np.abs(want))
    np.testing.assert_array_less(np.abs(got - want) / scale, tol)


def test_prediction_matches_highway_env(x64):
    """``predict_trajectory_constant_speed`` (the regulation's horizon): a copy steps with zero acceleration and
    the stored steering."""
    s = random_states(32, seed=1)
    n = len(PREDICTION_TIMES)
    px, py, ph = jax.jit(lambda *a: dynamics.predict_constant_steering(*a, 0.25, n))(
        *(jnp.asarray(s[k]) for k in ("x", "y", "heading", "speed", "lateral_speed", "yaw_rate", "steering",
                                      "crashed")))
    for i in range(32):
        positions, headings = highway_env_vehicle(s, i).predict_trajectory_constant_speed(PREDICTION_TIMES)
        want = np.array([[p[0], p[1], h] for p, h in zip(positions, headings)])
        got = np.stack([np.asarray(px[i]), np.asarray(py[i]), np.asarray(ph[i])], axis=1)
        np.testing.assert_array_less(np.abs(got - want) / np.maximum(1.0, np.abs(want)), 1e-10)


def test_float32_close_and_finite():
    """The default precision: finite, and one step within float32 rounding of highway-env's float64."""
    s = random_states(64, seed=2)
    out = jax.jit(lambda *a: dynamics.step(*a, DT))(
        *(jnp.asarray(s[k], jnp.float32) for k in ("x", "y", "heading", "speed", "lateral_speed", "yaw_rate",
                                                   "steering", "acceleration")), jnp.asarray(s["crashed"]))
    assert all(a.dtype == jnp.float32 for a in out)
    got = np.stack([np.asarray(a, np.float64) for a in out[:6]], axis=1)
    vs = [highway_env_vehicle(s, i) for i in range(64)]
    for v in vs:
        v.step(DT)
    want = np.array([vehicle_row(v) for v in vs])
    assert np.all(np.isfinite(got))
    np.testing.assert_array_less(np.abs(got - want) / np.maximum(1.0, np.abs(want)), 1e-4)
