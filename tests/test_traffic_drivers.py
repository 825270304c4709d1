"""IDM, MOBIL, the neighbour search and ``road.act`` of envs_jax against highway-env's own functions.

Random scenes (x64) on highway-env's roads: the straight highway and the roundabout
(curved lanes, so lane-longitudinal gaps differ from Euclidean ones). Each JAX
function is compared with the highway-env method it reproduces, called on the same
vehicles: ``Road.neighbour_vehicles``, ``IDMVehicle.acceleration``,
``IDMVehicle.mobil`` (random politeness, routes that fix a lane) and a whole frame of
``Road.act()`` (MDP and IDM vehicles interleaved, vehicles mid-lane-change, crashed
ones, timers around the lane-change delay, so that the abort rule and its list-order
dependence occur).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from highway_env.road.road import Road as HRoad
from highway_env.road.road import RoadNetwork as HNetwork
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import MDPVehicle
from highway_env.vehicle.objects import Obstacle

from envs_jax import drivers, idm
from envs_jax import neighbours as N
from envs_jax.mobil import ObjectTable, mobil, pair_acceleration
from envs_jax.scenarios import highway, roundabout
from envs_jax.traffic_state import TrafficState
from tests.traffic_oracle import lane_numbers

TARGET_SPEEDS = np.array([20.0, 25.0, 30.0])


def roundabout_roads():
    from highway_env.envs.roundabout_env import RoundaboutEnv

    env = RoundaboutEnv()
    env.reset(seed=0)
    return env.road.network, roundabout.build_road()


def highway_roads(lanes):
    return HNetwork.straight_road_network(lanes, speed_limit=30), highway.build_road(lanes)


def random_scene(rng, network, n, spread=None):
    """Vehicles on random lanes of ``network``: (lane index, s, lat, heading offset, speed, kind)."""
    names = list(lane_numbers(network))
    out = []
    for _ in range(n):
        name = names[rng.integers(len(names))]
        lane = network.get_lane(name)
        s = rng.uniform(0, spread if spread else lane.length)
        lat = rng.uniform(-2.5, 2.5) if rng.random() < 0.4 else rng.uniform(-0.3, 0.3)
        out.append((name, min(s, lane.length), lat, rng.normal(0, 0.1), rng.uniform(-1, 32), rng.random() < 0.3))
    return out


def build_vehicles(rng, network, scene, politeness=0.0):
    """highway-env vehicles of a scene: MDP (kind True) or IDM with random targets, timers and exponents."""
    road = HRoad(network=network, np_random=np.random.RandomState(0))
    vehicles = []
    for name, s, lat, dh, v, mdp in scene:
        lane = network.get_lane(name)
        pos = lane.position(s, lat)
        h = lane.heading_at(s) + dh
        side = network.side_lanes(name)
        target = side[rng.integers(len(side))] if side and rng.random() < 0.35 else None
        if mdp:
            veh = MDPVehicle(road, pos, h, v, target_lane_index=target,
                             target_speed=float(TARGET_SPEEDS[rng.integers(3)]), target_speeds=TARGET_SPEEDS)
        else:
            veh = IDMVehicle(road, pos, h, v, target_lane_index=target, target_speed=float(rng.uniform(10, 36)))
            veh.timer = float(rng.uniform(0.5, 1.5))
            veh.DELTA = float(rng.uniform(3.5, 4.5))
            veh.POLITENESS = politeness
        veh.crashed = bool(rng.random() < 0.1)
        vehicles.append(veh)
    road.vehicles = vehicles
    return road


def jax_state(road, numbers, dead=0, rng=None) -> tuple:
    """The TrafficState of highway-env's vehicles (plus ``dead`` empty slots with junk values)."""
    vs = road.vehicles
    lane_of = lambda idx: numbers[(idx[0], idx[1], int(idx[2]))]
    f = lambda vals, junk=0.0: np.concatenate([np.asarray(vals, np.float64), np.full(dead, junk)])
    b = lambda vals: np.concatenate([np.asarray(vals, bool), np.zeros(dead, bool)])
    i = lambda vals: np.concatenate([np.asarray(vals, np.int32), np.zeros(dead, np.int32)])
    n = len(vs) + dead
    junk_x = 0.0 if rng is None else float(vs[0].position[0])  # a dead slot right on top of a vehicle
    st = TrafficState(
        x=jnp.asarray(f([v.position[0] for v in vs], junk_x)), y=jnp.asarray(f([v.position[1] for v in vs],
                                                                                float(vs[0].position[1]))),
        heading=jnp.asarray(f([v.heading for v in vs])), speed=jnp.asarray(f([v.speed for v in vs], 20.0)),
        alive=jnp.asarray(b([True] * len(vs))), crashed=jnp.asarray(b([v.crashed for v in vs])),
        on_road=jnp.asarray(b([True] * len(vs))), lane=jnp.asarray(i([lane_of(v.lane_index) for v in vs])),
        target_lane=jnp.asarray(i([lane_of(v.target_lane_index) for v in vs])),
        target_speed=jnp.asarray(f([v.target_speed for v in vs], 20.0)),
        speed_index=jnp.asarray(i([getattr(v, "speed_index", 0) for v in vs])),
        steering=jnp.zeros(n), acceleration=jnp.zeros(n), impact=jnp.zeros((n, 2)), has_impact=jnp.zeros(n, bool),
        timer=jnp.asarray(f([getattr(v, "timer", 0.0) for v in vs], 5.0)),
        delta=jnp.asarray(f([getattr(v, "DELTA", 4.0) for v in vs])),
        route_roads=-jnp.ones((n, 1), jnp.int32), route_ids=-jnp.ones((n, 1), jnp.int32),
        route_len=jnp.zeros(n, jnp.int32), route_ptr=jnp.zeros(n, jnp.int32), time=jnp.zeros((), jnp.int32))
    is_mdp = np.concatenate([[isinstance(v, MDPVehicle) for v in vs], np.zeros(dead, bool)])
    is_idm = np.concatenate([[isinstance(v, IDMVehicle) for v in vs], np.ones(dead, bool)])
    return st, is_idm, is_mdp


def object_table(jroad, st, lanes_of_objects=None):
    s, _ = N.coordinates_on(jroad.lanes, st.lane, st.x, st.y)
    return ObjectTable(speed=st.speed, cos_h=jnp.cos(st.heading), sin_h=jnp.sin(st.heading),
                       target_speed=st.target_speed, speed_limit=jroad.lanes.col("speed_limit")[st.lane],
                       is_vehicle=jnp.ones(st.x.shape, bool),
                       s_own=s)


@pytest.mark.parametrize("road_name", ["highway", "roundabout"])
def test_neighbour_vehicles(road_name, x64):
    """``Road.neighbour_vehicles`` on random lanes, with obstacles among the road objects."""
    rng = np.random.default_rng(1)
    network, jroad = roundabout_roads() if road_name == "roundabout" else highway_roads(4)
    numbers = lane_numbers(network)
    names = list(numbers)
    checked = found = 0
    for trial in range(8):
        scene = random_scene(rng, network, 14, spread=None if road_name == "roundabout" else 150)
        road = build_vehicles(rng, network, scene)
        for _ in range(3):
            lane = network.get_lane(names[rng.integers(len(names))])
            road.objects.append(Obstacle(road, lane.position(rng.uniform(0, lane.length), 0)))
        search = jax.jit(lambda e, q, px, py, valid: N.neighbour_vehicles(jroad.lanes, e, q, px, py, valid))
        px = jnp.asarray([o.position[0] for o in road.vehicles + road.objects])
        py = jnp.asarray([o.position[1] for o in road.vehicles + road.objects])
        valid = jnp.ones(px.shape, bool)
        for ego in range(len(road.vehicles)):
            for q in [None] + [names[rng.integers(len(names))] for _ in range(3)]:
                q = road.vehicles[ego].lane_index if q is None else q
                ef, er = road.neighbour_vehicles(road.vehicles[ego], q)
                f, r = search(ego, numbers[q], px, py, valid)
                objs = road.vehicles + road.objects
                want = [-1 if o is None else next(k for k, u in enumerate(objs) if u is o) for o in (ef, er)]
                assert [int(f), int(r)] == want, (trial, ego, q)
                checked += 1
                found += sum(w >= 0 for w in want)
    assert found > checked / 4  # many searches find neighbours (not a vacuous comparison)


@pytest.mark.parametrize("road_name", ["highway", "roundabout"])
def test_idm_acceleration(road_name, x64):
    """``IDMVehicle.acceleration(ego, front)`` for random pairs (ego IDM or MDP; front or none)."""
    rng = np.random.default_rng(2)
    network, jroad = roundabout_roads() if road_name == "roundabout" else highway_roads(3)
    numbers = lane_numbers(network)
    errs = []
    acc = jax.jit(lambda objs, e, f, d: pair_acceleration(objs, e, f, d, idm.IDMParams()))
    for _ in range(20):
        road = build_vehicles(rng, network, random_scene(rng, network, 10, spread=80))
        st, _, _ = jax_state(road, numbers)
        objs = object_table(jroad, st)
        for _ in range(10):
            me, e, f = rng.integers(10), rng.integers(10), rng.integers(-1, 10)
            decider = road.vehicles[me]
            if not isinstance(decider, IDMVehicle):
                continue
            want = decider.acceleration(road.vehicles[e], None if f < 0 else road.vehicles[f])
            got = acc(objs, e, f, st.delta[me])
            errs.append(abs(float(got) - want) / max(1.0, abs(want)))
    assert len(errs) > 50 and max(errs) < 1e-9


@pytest.mark.parametrize("road_name", ["highway", "roundabout"])
def test_mobil(road_name, x64):
    """``IDMVehicle.mobil(lane)`` for every side lane of random vehicles; random politeness and routes."""
    rng = np.random.default_rng(3)
    network, jroad = roundabout_roads() if road_name == "roundabout" else highway_roads(4)
    numbers = lane_numbers(network)
    outcomes = []
    search = jax.jit(lambda e, q, px, py, valid: N.neighbour_vehicles(jroad.lanes, e, q, px, py, valid))
    decide = jax.jit(mobil)
    for trial in range(30):
        politeness = float(rng.choice([0.0, 0.3, 1.0]))
        road = build_vehicles(rng, network, random_scene(rng, network, 12, spread=100), politeness)
        st, _, _ = jax_state(road, numbers)
        objs = object_table(jroad, st)
        px, py, valid = st.x, st.y, st.alive
        p = idm.IDMParams(politeness=politeness)
        for me, v in enumerate(road.vehicles):
            if not isinstance(v, IDMVehicle):
                continue
            route_id = -1
            if rng.random() < 0.4:  # a route whose head fixes a lane id
                route_id = int(rng.integers(len(network.graph[v.lane_index[0]][v.lane_index[1]])))
                v.route = [(v.lane_index[0], v.lane_index[1], route_id)]
            for side in network.side_lanes(v.lane_index):
                want = v.mobil(side)
                op, of = search(me, st.lane[me], px, py, valid)
                np_, nf = search(me, numbers[side], px, py, valid)
                got = decide(objs, me, np_, nf, op, of, side[2], v.target_lane_index[2], route_id >= 0,
                            route_id, st.delta[me], p)
                assert bool(got) == bool(want), (trial, me, side)
                outcomes.append(bool(want))
    assert 0.1 < np.mean(outcomes) < 0.9  # both answers occur


@pytest.mark.parametrize("group", ["default", 1, "every"])
@pytest.mark.parametrize("lanes,dead", [(3, 0), (4, 3)])
def test_road_act(lanes, dead, group, x64, monkeypatch):
    """A frame of ``Road.act()``: target lanes, timers and commands of every vehicle, in list order.

    Dense traffic with vehicles mid-lane-change makes the abort rule fire, including cases
    where an earlier vehicle's decision of the same frame changes a later one's. Empty
    slots (``dead``, one of them on top of a vehicle) must change nothing. About half the
    drivers decide on each frame here, so the deciding drivers' groups (``group`` at a time:
    the default quarter of the slots, one, or every slot at once) overflow into further rounds.
    All 40 frames also run as one batch under ``vmap`` (groups of one: the deciding drivers of the whole batch
    packed into several chunks, ``sparse.batch_rows``).
    """
    if group != "default":
        monkeypatch.setattr(drivers, "decision_rows", lambda n: n if group == "every" else group)
    rng = np.random.default_rng(4 + lanes)
    network, jroad = highway_roads(lanes)
    numbers = lane_numbers(network)
    aborts = changes = 0
    act = jax.jit(lambda s, is_idm, is_mdp: drivers.road_act(jroad, s, is_idm, is_mdp, idm.IDMParams()))
    frames = []

    for trial in range(40):
        road = build_vehicles(rng, network, random_scene(rng, network, 16, spread=120))
        st, is_idm, is_mdp = jax_state(road, numbers, dead=dead, rng=rng)
        before = [v.target_lane_index for v in road.vehicles]
        road.act()
        out = act(st, is_idm, is_mdp)
        n = len(road.vehicles)
        want_target = [numbers[(v.target_lane_index[0], v.target_lane_index[1], int(v.target_lane_index[2]))]
                       for v in road.vehicles]
        np.testing.assert_array_equal(np.asarray(out.target_lane)[:n], want_target, err_msg=f"trial {trial}")
        want_timer = [getattr(v, "timer", 0.0) for v in road.vehicles]
        np.testing.assert_allclose(np.asarray(out.timer)[:n], want_timer, rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.asarray(out.steering)[:n], [v.action["steering"] for v in road.vehicles],
                                   rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.asarray(out.acceleration)[:n],
                                   [v.action["acceleration"] for v in road.vehicles], rtol=0, atol=1e-9)
        for v, b in zip(road.vehicles, before):
            changes += v.target_lane_index != b
            aborts += (b != v.lane_index) and (v.target_lane_index == v.lane_index)
        frames.append((st, is_idm, is_mdp, out))
    assert changes > 20 and aborts > 3, (changes, aborts)
    assert len({f[0].x.shape for f in frames}) == 1  # one slot count: the frames stack into a batch
    batch = [jax.tree_util.tree_map(lambda *a: jnp.stack(a), *(f[i] for f in frames)) for i in range(3)]
    batched = jax.jit(jax.vmap(lambda s, is_idm, is_mdp: drivers.road_act(jroad, s, is_idm, is_mdp,
                                                                          idm.IDMParams())))(*batch)
    for t, (*_, out) in enumerate(frames):
        for field in ("target_lane", "timer", "steering", "acceleration"):
            np.testing.assert_allclose(np.asarray(getattr(batched, field))[t], np.asarray(getattr(out, field)),
                                       rtol=0, atol=1e-12, err_msg=f"{field}, frame {t} of the batch")
