"""``lane_locate.locate`` (the simulator's closest-lane search, with the sine lanes' trigonometry run only
where a lower bound lets a sine lane win) against the brute-force all-lane search and highway-env,
on random poses and on adversarial ones: lane ends, lane borders, sine lanes' crests, headings at
the sine lanes' steepest slope."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from envs_jax import all_lanes as AL
from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from tests.highway_oracle import make_oracle_env, oracle_lanes

SCENARIOS = ["merge", "roundabout", "intersection", "racetrack"]
BOX = {"merge": ([-20, -10], [480, 25]), "roundabout": ([-180, -180], [180, 180]),
       "intersection": ([-120, -120], [120, 120]), "racetrack": ([-60, -80], [160, 80])}


def _poses(name: str, n_random: int = 4000):
    """Random poses in the map's box, plus poses placed on every lane at its ends and borders."""
    rng = np.random.default_rng(7)
    lo, hi = BOX[name]
    pts = [rng.uniform(lo, hi, size=(n_random, 2))]
    heads = [rng.uniform(-4, 4, n_random)]
    for _, _, _, lane in oracle_lanes(name):
        slope = np.arctan(abs(getattr(lane, "amplitude", 0.0) * getattr(lane, "pulsation", 0.0)))
        for s in (-5.01, -2.5, -1e-6, 0.0, 1e-6, lane.length / 3, lane.length - 2.5, lane.length - 1e-6,
                  lane.length, lane.length + 1e-6, lane.length + 5.0):
            for lat in (0.0, 1.9, -2.0, 2.1, -4.0, 5.0, -8.0):
                p = lane.position(s, lat)
                h = lane.heading_at(s)
                for dh in (0.0, slope, -slope - 1e-3, 0.7, np.pi):
                    pts.append(np.array([p]))
                    heads.append(np.array([h + dh]))
    return np.concatenate(pts), np.concatenate(heads)


def _dense(lanes, px, py, h):
    cost, s_all, lat_all = AL.distance_with_heading_all(lanes, px, py, h)
    lane = AL.first_argmin(cost)
    pick = lambda a: jnp.take_along_axis(a, lane[:, None], axis=-1)[:, 0]
    return lane, pick(s_all), pick(lat_all), cost


@pytest.mark.parametrize("name", SCENARIOS)
def test_locate_equals_brute_force_x64(name, x64):
    """Same lane as the all-lane argmin on every pose, and the same (s, lat) on it."""
    lanes = envs_jax.make(name).road.lanes
    pts, heads = _poses(name)
    px, py, h = (jnp.asarray(a) for a in (pts[:, 0], pts[:, 1], heads))
    lane, s, lat, _ = jax.jit(jax.vmap(lambda a, b, c: LL.locate(lanes, a, b, c)))(px, py, h)
    ref_lane, ref_s, ref_lat, _ = jax.jit(lambda a, b, c: _dense(lanes, a, b, c))(px, py, h)
    np.testing.assert_array_equal(np.asarray(lane), np.asarray(ref_lane))
    np.testing.assert_allclose(np.asarray(s), np.asarray(ref_s), rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(lat), np.asarray(ref_lat), rtol=0, atol=1e-9)


def _assert_same_lane_up_to_ties(lane, ref_lane, cost):
    """Equal lanes, except where the two lanes' costs tie to float32 round-off (poses on lane junctions: about half
    of :func:`_poses`' placed poses sit on a lane's end, where the next lane starts; with one heading shared by every
    pose, as in :func:`test_locate_batched_rules_agree`, 3.5% of all poses tie there)."""
    lane, ref_lane, cost = np.asarray(lane), np.asarray(ref_lane), np.asarray(cost)
    diff = np.nonzero(lane != ref_lane)[0]
    gap = np.abs(cost[diff, lane[diff]] - cost[diff, ref_lane[diff]])
    assert len(diff) <= 0.05 * len(lane) and np.all(gap <= 1e-4 * (1 + cost[diff, ref_lane[diff]])), diff
    return lane == ref_lane


@pytest.mark.parametrize("name", SCENARIOS)
def test_locate_equals_brute_force_float32(name):
    """In float32 too; a different lane only where the two lanes' costs tie to round-off."""
    assert not jax.config.jax_enable_x64
    lanes = envs_jax.make(name).road.lanes
    pts, heads = _poses(name)
    px, py, h = (jnp.asarray(a, jnp.float32) for a in (pts[:, 0], pts[:, 1], heads))
    lane, s, lat, _ = jax.jit(jax.vmap(lambda a, b, c: LL.locate(lanes, a, b, c)))(px, py, h)
    ref_lane, ref_s, ref_lat, cost = jax.jit(lambda a, b, c: _dense(lanes, a, b, c))(px, py, h)
    same = _assert_same_lane_up_to_ties(lane, ref_lane, cost)
    np.testing.assert_allclose(np.asarray(s)[same], np.asarray(ref_s)[same], rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(np.asarray(lat)[same], np.asarray(ref_lat)[same], rtol=1e-6, atol=1e-4)


@pytest.mark.parametrize("name", SCENARIOS)
def test_locate_matches_highway_env(name, x64):
    """``get_closest_lane_index`` itself; a different lane only on a round-off tie of highway-env's costs."""
    env = envs_jax.make(name)
    oracle = make_oracle_env(name)
    oracle.reset()
    net = oracle.road.network
    number = {n: i for i, n in enumerate(env.road.lane_names)}
    pts, heads = _poses(name, n_random=1000)
    pick = np.random.default_rng(3).choice(len(pts), size=min(len(pts), 2500), replace=False)
    pts, heads = pts[pick], heads[pick]
    ours = np.asarray(jax.jit(jax.vmap(lambda a, b, c: LL.locate(env.road.lanes, a, b, c)[0]))(
        jnp.asarray(pts[:, 0]), jnp.asarray(pts[:, 1]), jnp.asarray(heads)))
    lanes = [lane for _, _, _, lane in oracle_lanes(name)]
    for k, (p, h) in enumerate(zip(pts, heads)):
        theirs = number[net.get_closest_lane_index(p, h)]
        if ours[k] != theirs:
            gap = abs(lanes[ours[k]].distance_with_heading(p, h) - lanes[theirs].distance_with_heading(p, h))
            assert gap <= 1e-9, (p, h, ours[k], theirs)


@pytest.mark.parametrize("name", ["merge", "roundabout"])
def test_sine_lower_bound_is_a_lower_bound(name, x64):
    """The bound never exceeds a sine lane's exact distance-with-heading (so it never drops the closest lane)."""
    lanes = envs_jax.make(name).road.lanes
    pts, heads = _poses(name)
    rows = lanes.sine_rows
    r = {f: lanes.col(f, rows) for f in L.FIELDS}
    px, py, h = (jnp.asarray(a)[:, None] for a in (pts[:, 0], pts[:, 1], heads))
    s, lat_base = L.linear_local(r, px, py)
    bound = np.asarray(LL.sine_lower_bound(r, s, lat_base, h))
    exact = np.asarray(AL.distance_with_heading_all(lanes, px[:, 0], py[:, 0], h[:, 0])[0])[:, rows]
    assert np.all(bound <= exact + 1e-12)
    assert np.mean(bound > 1.0) > 0.5  # and it is not vacuous: most poses rule the sine lanes out


def test_locate_batched_rules_agree():
    """The custom vmap rule (flattened batch), nested vmaps, an unbatched argument and the unbatched call
    give the brute-force result (float32, up to round-off ties)."""
    lanes = envs_jax.make("roundabout").road.lanes
    pts, heads = _poses("roundabout", n_random=600)
    n = (len(pts) // 6) * 6
    px, py, h = (jnp.asarray(a[:n], jnp.float32) for a in (pts[:, 0], pts[:, 1], heads))
    flat = jax.jit(lambda a, b, c: LL.locate(lanes, a, b, c))(px, py, h)
    nested = jax.jit(jax.vmap(jax.vmap(lambda a, b, c: LL.locate(lanes, a, b, c))))(
        px.reshape(-1, 3, 2), py.reshape(-1, 3, 2), h.reshape(-1, 3, 2))
    shared = jax.jit(jax.vmap(lambda a, b: LL.locate(lanes, a, b, h[0])))(px, py)
    ref_lane, ref_s, ref_lat, cost = _dense(lanes, px, py, h)
    for got in (flat, jax.tree_util.tree_map(lambda a: a.reshape((n,) + a.shape[3:]), nested)):
        same = _assert_same_lane_up_to_ties(got[0], ref_lane, cost)
        np.testing.assert_allclose(np.asarray(got[1])[same], np.asarray(ref_s)[same], atol=1e-4)
        np.testing.assert_allclose(np.asarray(got[2])[same], np.asarray(ref_lat)[same], atol=1e-4)
    ref_lane, _, _, cost = _dense(lanes, px, py, jnp.full_like(h, h[0]))
    _assert_same_lane_up_to_ties(shared[0], ref_lane, cost)


@pytest.mark.parametrize("name", SCENARIOS)
def test_lane_coords_equal_local_coordinates(name, x64):
    """``lane_coords`` from the position and its circle coordinates = ``local_coordinates`` on every lane."""
    lanes = envs_jax.make(name).road.lanes
    rng = np.random.default_rng(5)
    lo, hi = BOX[name]
    pts = jnp.asarray(rng.uniform(lo, hi, size=(300, 2)))
    for k in range(lanes.size):
        idx = jnp.full(300, k, jnp.int32)
        circles = LL.circle_coords(lanes, pts[:, 0], pts[:, 1])
        s, lat = LL.lane_coords(lanes, pts[:, 0], pts[:, 1], circles, idx)
        es, elat = L.local_coordinates(lanes, idx, pts[:, 0], pts[:, 1])
        np.testing.assert_allclose(np.asarray(s), np.asarray(es), rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.asarray(lat), np.asarray(elat), rtol=0, atol=1e-9)


@pytest.mark.parametrize("name, n_query", [("merge", None), ("roundabout", None), ("roundabout", 5),
                                           ("racetrack", None)])
def test_lane_coords_broadcast_query_lanes(name, n_query, x64):
    """Few query lanes against many points (``idx [Q, 1]``, ``px [N]``, circle coordinates ``[N, C]``, as
    ``neighbours.coordinates_on`` calls it) = ``local_coordinates`` point by point, on every lane (or on
    ``n_query`` of them, the sine lanes among them: with fewer query lanes than sine lanes the sine offsets are
    evaluated per query lane, otherwise once per point and sine lane)."""
    from envs_jax import neighbours
    lanes = envs_jax.make(name).road.lanes
    assert lanes.sine_rows.size or lanes.circle_centers.shape[0]
    rng = np.random.default_rng(11)
    lo, hi = BOX[name]
    pts = jnp.asarray(rng.uniform(lo, hi, size=(200, 2)))
    rows = np.arange(lanes.size) if n_query is None else np.concatenate(
        [lanes.sine_rows[:3], np.setdiff1d(np.arange(lanes.size), lanes.sine_rows)[:n_query - 3]])
    query = jnp.asarray(rows, jnp.int32)
    s, lat = neighbours.coordinates_on(lanes, query, pts[:, 0], pts[:, 1])
    assert s.shape == (len(rows), 200)
    idx = jnp.broadcast_to(query[:, None], s.shape)
    px, py = jnp.broadcast_to(pts[:, 0], s.shape), jnp.broadcast_to(pts[:, 1], s.shape)
    es, elat = L.local_coordinates(lanes, idx, px, py)
    np.testing.assert_allclose(np.asarray(s), np.asarray(es), rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(lat), np.asarray(elat), rtol=0, atol=1e-9)
