"""Lane geometry and road network against highway-env's own lane objects and closed forms."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import envs_jax
from envs_jax import lanes as L
from tests.highway_oracle import make_oracle_env, oracle_lanes

SCENARIOS = ["merge", "roundabout"]


def _env(name):
    return envs_jax.make(name)


@pytest.mark.parametrize("name", SCENARIOS)
def test_lane_table_matches_highway_env(name, x64):
    """Same lanes, same order (the closest-lane scan order), same length, width, forbidden flag."""
    env = _env(name)
    theirs = oracle_lanes(name)
    assert env.road.lane_names == [(f, t, i) for f, t, i, _ in theirs]
    for k, (_, _, _, lane) in enumerate(theirs):
        assert env.road.lanes.np_col("length")[k] == pytest.approx(lane.length, abs=1e-12)
        assert env.road.lanes.np_col("width")[k] == lane.width_at(0)
        assert bool(env.road.lanes.forbidden[k]) == bool(lane.forbidden)


@pytest.mark.parametrize("name", SCENARIOS)
def test_lane_functions_match_highway_env(name, x64):
    """local_coordinates, position, heading_at, on_lane, is_reachable_from, after_end, distance."""
    env = _env(name)
    # each function compiled once, the lane index traced (op-by-op dispatch made this test slow)
    fn = {f: jax.jit(lambda k, a, b, f=f: getattr(L, f)(env.road.lanes, k, a, b))
          for f in ("local_coordinates", "position", "on_lane", "is_reachable_from", "after_end", "distance")}
    heading_at = jax.jit(lambda k, s: L.heading_at(env.road.lanes, k, s))
    rng = np.random.default_rng(0)
    for k, (_, _, _, lane) in enumerate(oracle_lanes(name)):
        for _ in range(20):
            s0, r0 = rng.uniform(-10, lane.length + 10), rng.uniform(-6, 6)
            p = lane.position(s0, r0)
            s, lat = fn["local_coordinates"](k, p[0], p[1])
            es, elat = lane.local_coordinates(p)
            assert float(s) == pytest.approx(es, abs=1e-9) and float(lat) == pytest.approx(elat, abs=1e-9)
            assert float(heading_at(k, s0)) == pytest.approx(lane.heading_at(s0), abs=1e-12)
            x, y = fn["position"](k, s0, r0)
            np.testing.assert_allclose([float(x), float(y)], p, atol=1e-9)
            assert bool(fn["on_lane"](k, p[0], p[1])) == bool(lane.on_lane(p))
            assert bool(fn["is_reachable_from"](k, p[0], p[1])) == bool(lane.is_reachable_from(p))
            assert bool(fn["after_end"](k, p[0], p[1])) == bool(lane.after_end(p))
            assert float(fn["distance"](k, p[0], p[1])) == pytest.approx(lane.distance(p), abs=1e-9)


@pytest.mark.parametrize("name", SCENARIOS)
def test_closest_lane_matches_highway_env(name, x64):
    """``get_closest_lane_index`` over random poses, including the heading term and ties."""
    env = _env(name)
    oracle = make_oracle_env(name)
    oracle.reset()
    net = oracle.road.network
    number = {n: i for i, n in enumerate(env.road.lane_names)}
    rng = np.random.default_rng(1)
    lo, hi = ((np.array([-20, -10]), np.array([480, 25])) if name == "merge"
              else (np.array([-180, -180]), np.array([180, 180])))
    pts = rng.uniform(lo, hi, size=(400, 2))
    heads = rng.uniform(-4, 4, size=400)
    ours = np.asarray(jax.vmap(env.road.closest_lane)(jnp.asarray(pts[:, 0]), jnp.asarray(pts[:, 1]),
                                                      jnp.asarray(heads)))
    theirs = [number[net.get_closest_lane_index(p, h)] for p, h in zip(pts, heads)]
    np.testing.assert_array_equal(ours, theirs)


@pytest.mark.parametrize("name", SCENARIOS)
def test_next_lane_matches_highway_env(name, x64):
    """``next_lane`` without a route from the end of every lane, at several lateral offsets."""
    env = _env(name)
    oracle = make_oracle_env(name)
    oracle.reset()
    net = oracle.road.network
    number = {n: i for i, n in enumerate(env.road.lane_names)}
    R = env.scenario.route_length
    empty = (-jnp.ones(R, jnp.int32), -jnp.ones(R, jnp.int32), jnp.int32(0), jnp.int32(0))
    for k, (f, t, i, lane) in enumerate(oracle_lanes(name)):
        for lat in (-1.5, 0.0, 1.5):
            p = lane.position(lane.length - 1.0, lat)
            s, _ = L.local_coordinates(env.road.lanes, k, p[0], p[1])
            ours, _ = env.road.next_lane(jnp.int32(k), s, *empty)
            theirs = net.next_lane((f, t, i), route=None, position=p)
            assert int(ours) == number[theirs], (f, t, i, lat)


@settings(max_examples=200, deadline=None)
@given(k=st.integers(0, 31), s=st.floats(0, 1), lat=st.floats(-2, 2))
def test_position_local_coordinates_round_trip(k, s, lat):
    """position(s, lat) -> local_coordinates gives (s, lat) back on every lane kind."""
    with jax.enable_x64(True):
        lanes = _env("roundabout").road.lanes
        length = lanes.np_col("length")[k]
        x, y = L.position(lanes, k, s * length, lat)
        s2, lat2 = L.local_coordinates(lanes, k, x, y)
        assert float(s2) == pytest.approx(s * length, abs=1e-9)
        if lanes.kind[k] != L.SINE:  # a sine lane's lateral offset is measured along the chord normal
            assert float(lat2) == pytest.approx(lat, abs=1e-9)


def test_circular_lane_closed_form(x64):
    """A ring lane: s = R * swept angle, lat = r - R (counter-clockwise), heading tangent."""
    lanes = _env("roundabout").road.lanes
    k = 0  # se->ex, radius 20, from 66 deg down to 24 deg (clockwise=False)
    R, phi0 = 20.0, np.deg2rad(66)
    for dphi, r in [(0.1, 20.0), (0.5, 23.0), (0.7, 18.5)]:
        phi = phi0 - dphi
        s, lat = L.local_coordinates(lanes, k, r * np.cos(phi), r * np.sin(phi))
        assert float(s) == pytest.approx(R * dphi, abs=1e-9)
        assert float(lat) == pytest.approx(r - R, abs=1e-9)
        assert float(L.heading_at(lanes, k, R * dphi)) == pytest.approx(phi - np.pi / 2, abs=1e-12)


def test_sine_lane_closed_form(x64):
    """Merge ramp k->b: centre line y = 11.25 + 3.25 cos(pi s / 80) from x = 150 to 230."""
    env = _env("merge")
    k = env.road.lane("k", "b", 0)
    for s in [0.0, 20.0, 40.0, 80.0]:
        x, y = L.position(env.road.lanes, k, s, 0.0)
        assert float(x) == pytest.approx(150 + s, abs=1e-9)
        assert float(y) == pytest.approx(11.25 + 3.25 * np.cos(np.pi * s / 80), abs=1e-9)


def test_wrap_to_pi_matches_numpy(x64):
    x = np.linspace(-50, 50, 100001)
    np.testing.assert_allclose(np.asarray(L.wrap_to_pi(jnp.asarray(x))), ((x + np.pi) % (2 * np.pi)) - np.pi,
                               atol=1e-12)
