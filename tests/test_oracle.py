"""Self-checks of the highway-env oracle (tests/highway_oracle.py) against docs/scenarios.md.

Every figure below is a roll-out or table that the spec obtained by running the authors' own fork
(highway-env v1.7.1 + their four env files).  Reproducing them with highway-env 1.12.1 + our
subclasses is what makes the oracle trustworthy as the reference for the JAX simulator.

Action indices (DiscreteMetaAction): 0 LANE_LEFT, 1 IDLE, 2 LANE_RIGHT, 3 FASTER, 4 SLOWER.
Time convention: ``state[k]`` / ``obs[k]`` is the state after k decisions (t = k), ``reward[k-1]`` etc.
belong to decision k.  "at t=k" in docs/scenarios.md means after the k-th decision.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
from highway_env.road.lane import CircularLane, LineType, SineLane, StraightLane

from tests.highway_oracle import SCENARIOS, make_oracle_env, oracle_lanes, run_oracle

LANE_LEFT, IDLE, LANE_RIGHT, FASTER, SLOWER = range(5)
N, S, C, CL = LineType.NONE, LineType.STRIPED, LineType.CONTINUOUS, LineType.CONTINUOUS_LINE


@functools.lru_cache(maxsize=None)
def _run(scenario: str, leader, follower, steps: int = 20):
    """Constant-action roll-out (cached: several tests look at the same episode)."""
    actions = np.tile(np.array([leader, follower]), (steps, 1))
    return run_oracle(scenario, actions)


def _first(flags) -> int:
    """First index where ``flags`` is True (-1 if never)."""
    flags = np.asarray(flags)
    return int(np.argmax(flags)) if flags.any() else -1


# --------------------------------------------------------------------------------------------------
# Geometry: highway-env's own _make_road must equal the lane tables of docs/scenarios.md
# --------------------------------------------------------------------------------------------------


def _check_straight(lane, start, end, lines, width=4.0, forbidden=False, speed=20.0, priority=0):
    assert type(lane) is StraightLane
    np.testing.assert_allclose(lane.start, start, atol=1e-9)
    np.testing.assert_allclose(lane.end, end, atol=1e-9)
    assert list(lane.line_types) == list(lines)
    assert (lane.width, bool(lane.forbidden), lane.speed_limit, lane.priority) == (width, forbidden, speed, priority)


def _check_sine(lane, start, end, amplitude, pulsation, phase, lines, forbidden=False, speed=20.0):
    assert type(lane) is SineLane
    np.testing.assert_allclose(lane.start, start, atol=1e-9)
    np.testing.assert_allclose(lane.end, end, atol=1e-9)
    np.testing.assert_allclose([lane.amplitude, lane.pulsation, lane.phase], [amplitude, pulsation, phase], atol=1e-9)
    assert list(lane.line_types) == list(lines)
    assert (lane.width, bool(lane.forbidden), lane.speed_limit) == (4.0, forbidden, speed)


def _check_circle(lane, center, radius, phases_deg, clockwise, lines, length=None, width=4.0, speed=20.0,
                  priority=0):
    assert type(lane) is CircularLane
    np.testing.assert_allclose(lane.center, center, atol=1e-9)
    assert lane.radius == radius
    np.testing.assert_allclose(np.rad2deg([lane.start_phase, lane.end_phase]), phases_deg, atol=1e-9)
    assert lane.clockwise == clockwise
    assert list(lane.line_types) == list(lines)
    assert (lane.width, lane.speed_limit, lane.priority) == (width, speed, priority)
    if length is not None:
        assert lane.length == pytest.approx(length, abs=0.005)


def _lane_dict(scenario):
    return {(f, t, i): lane for f, t, i, lane in oracle_lanes(scenario)}


def test_lane_order_is_graph_order():
    """oracle_lanes = road.network.graph iteration order (= get_closest_lane_index scan order)."""
    expected = {
        "merge": ["a-b-0", "a-b-1", "b-c-0", "b-c-1", "b-c-2", "c-d-0", "c-d-1", "j-k-0", "k-b-0"],
        "racetrack": [f"{a}-{b}-{i}" for a, b in zip("abcdefghi", "bcdefghia") for i in (0, 1)],
    }
    for scenario, keys in expected.items():
        assert [f"{f}-{t}-{i}" for f, t, i, _ in oracle_lanes(scenario)] == keys
    for scenario in SCENARIOS:
        env = make_oracle_env(scenario)
        assert [(f, t, i) for f, t, i, _ in oracle_lanes(scenario)] == list(env.road.network.lanes_dict().keys())
    assert len(oracle_lanes("roundabout")) == 32 and len(oracle_lanes("intersection")) == 20


def test_merge_geometry():  # docs/scenarios.md, lane tables
    lanes = _lane_dict("merge")
    assert len(lanes) == 9
    _check_straight(lanes["a", "b", 0], (0, 0), (230, 0), [CL, S])
    _check_straight(lanes["a", "b", 1], (0, 4), (230, 4), [N, CL])
    _check_straight(lanes["b", "c", 0], (230, 0), (310, 0), [CL, S])
    _check_straight(lanes["b", "c", 1], (230, 4), (310, 4), [N, S])
    _check_straight(lanes["b", "c", 2], (230, 8), (310, 8), [N, CL], forbidden=True)
    _check_straight(lanes["c", "d", 0], (310, 0), (460, 0), [CL, S])
    _check_straight(lanes["c", "d", 1], (310, 4), (460, 4), [N, CL])
    _check_straight(lanes["j", "k", 0], (0, 14.5), (150, 14.5), [CL, CL], forbidden=True)
    _check_sine(lanes["k", "b", 0], (150, 11.25), (230, 11.25), 3.25, 2 * np.pi / 160, np.pi / 2, [CL, CL],
                forbidden=True)
    # centre line y = 11.25 + 3.25 cos(pi s / 80): 14.5 -> 8
    np.testing.assert_allclose(lanes["k", "b", 0].position(0, 0), (150, 14.5), atol=1e-12)
    np.testing.assert_allclose(lanes["k", "b", 0].position(80, 0), (230, 8), atol=1e-12)
    env = make_oracle_env("merge")
    assert len(env.road.objects) == 1
    obstacle = env.road.objects[0]
    np.testing.assert_allclose(obstacle.position, (310, 8), atol=1e-12)
    assert (obstacle.LENGTH, obstacle.WIDTH, obstacle.heading, obstacle.speed, obstacle.solid) == (2, 2, 0, 0, True)


def test_roundabout_geometry():  # docs/scenarios.md, lane tables
    lanes = _lane_dict("roundabout")
    ring = [("se", "ex", 66, 24), ("ex", "ee", 24, -24), ("ee", "nx", -24, -66), ("nx", "ne", -66, -114),
            ("ne", "wx", -114, -156), ("wx", "we", -156, -204), ("we", "sx", 156, 114), ("sx", "se", 114, 66)]
    for a, b, p0, p1 in ring:
        arc = abs(p1 - p0)
        lengths = {42: (14.66, 17.59), 48: (16.76, 20.11)}[arc]
        _check_circle(lanes[a, b, 0], (0, 0), 20, (p0, p1), False, [C, S], lengths[0])
        _check_circle(lanes[a, b, 1], (0, 0), 24, (p0, p1), False, [N, C], lengths[1])
    w = 2 * np.pi / 85
    entry, exit_ = -np.pi / 2, -np.pi / 2 + 68 * w
    assert exit_ == pytest.approx(3.45575, abs=1e-5) and w == pytest.approx(0.0739198, abs=1e-7)
    straight = {
        ("ser", "ses"): ((2, 170), (2, 42.5), [S, C]), ("sxs", "sxr"): ((-2, 42.5), (-2, 170), [N, C]),
        ("eer", "ees"): ((170, -2), (42.5, -2), [S, C]), ("exs", "exr"): ((42.5, 2), (170, 2), [N, C]),
        ("ner", "nes"): ((-2, -170), (-2, -42.5), [S, C]), ("nxs", "nxr"): ((2, -42.5), (2, -170), [N, C]),
        ("wer", "wes"): ((-170, 2), (-42.5, 2), [S, C]), ("wxs", "wxr"): ((-42.5, -2), (-170, -2), [N, C]),
    }
    for (a, b), (p0, p1, lines) in straight.items():
        _check_straight(lanes[a, b, 0], p0, p1, lines)
    sine = {
        ("ses", "se"): ((7, 42.5), (7, 25.5), entry), ("sx", "sxs"): ((-7, 25.5), (-7, 42.5), exit_),
        ("ees", "ee"): ((42.5, -7), (25.5, -7), entry), ("ex", "exs"): ((25.5, 7), (42.5, 7), exit_),
        ("nes", "ne"): ((-7, -42.5), (-7, -25.5), entry), ("nx", "nxs"): ((7, -25.5), (7, -42.5), exit_),
        ("wes", "we"): ((-42.5, 7), (-25.5, 7), entry), ("wx", "wxs"): ((-25.5, -7), (-42.5, -7), exit_),
    }
    for (a, b), (p0, p1, phase) in sine.items():
        _check_sine(lanes[a, b, 0], p0, p1, 5, w, phase, [C, C])
        assert lanes[a, b, 0].length == pytest.approx(17)
    assert len(lanes) == 16 + 16
    assert lanes["ser", "ses", 0].length == pytest.approx(127.5)
    assert not make_oracle_env("roundabout").road.objects


def test_intersection_geometry():  # docs/scenarios.md, lane tables
    lanes = _lane_dict("intersection")
    assert len(lanes) == 20
    for c in range(4):
        th = np.deg2rad(90 * c)
        rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        prio = 3 if c % 2 else 1
        kw = dict(width=4.0, speed=10.0)
        _check_straight(lanes[f"o{c}", f"ir{c}", 0], rot @ (2, 111), rot @ (2, 11), [S, C], priority=prio, **kw)
        _check_circle(lanes[f"ir{c}", f"il{(c - 1) % 4}", 0], rot @ (11, 11), 9, (90 * c + 180, 90 * c + 270), True,
                      [N, C], priority=prio, **kw)
        _check_circle(lanes[f"ir{c}", f"il{(c + 1) % 4}", 0], rot @ (-11, 11), 13, (90 * c, 90 * c - 90), False,
                      [N, N], priority=prio - 1, **kw)
        _check_straight(lanes[f"ir{c}", f"il{(c + 2) % 4}", 0], rot @ (2, 11), rot @ (2, -11), [S, N], priority=prio,
                        **kw)
        _check_straight(lanes[f"il{(c - 1) % 4}", f"o{(c - 1) % 4}", 0], rot @ (11, 2), rot @ (111, 2), [N, C],
                        priority=prio, **kw)
    # the two paths of the agents
    np.testing.assert_allclose(lanes["ir0", "il2", 0].start, (2, 11), atol=1e-12)
    np.testing.assert_allclose(lanes["il2", "o2", 0].end, (2, -111), atol=1e-12)
    np.testing.assert_allclose(lanes["o1", "ir1", 0].start, (-111, 2), atol=1e-12)
    np.testing.assert_allclose(lanes["il3", "o3", 0].end, (111, 2), atol=1e-12)
    assert type(make_oracle_env("intersection").road).__name__ == "RegulatedRoad"


def test_racetrack_geometry():  # docs/scenarios.md, lane tables
    lanes = _lane_dict("racetrack")
    kw = dict(width=5.0, speed=10.0)
    _check_straight(lanes["a", "b", 0], (42, 0), (100, 0), [C, S], **kw)
    _check_straight(lanes["a", "b", 1], (42, 5), (100, 5), [S, C], **kw)
    assert lanes["a", "b", 0].length == 58
    _check_circle(lanes["b", "c", 0], (100, -20), 20, (90, -1), False, [C, N], 31.76, **kw)
    _check_circle(lanes["b", "c", 1], (100, -20), 25, (90, -1), False, [S, C], 39.71, **kw)
    _check_straight(lanes["c", "d", 0], (120, -20), (120, -30), [C, N], **kw)
    _check_straight(lanes["c", "d", 1], (125, -20), (125, -30), [S, C], **kw)
    _check_circle(lanes["d", "e", 0], (105, -30), 15, (0, -181), False, [C, N], 47.39, **kw)
    _check_circle(lanes["d", "e", 1], (105, -30), 20, (0, -181), False, [S, C], 63.18, **kw)
    _check_circle(lanes["e", "f", 0], (70, -30), 20, (0, 136), True, [C, S], 47.47, **kw)
    _check_circle(lanes["e", "f", 1], (70, -30), 15, (0, 137), True, [N, C], 35.87, **kw)
    _check_straight(lanes["f", "g", 0], (55.7, -15.7), (35.7, -35.7), [C, N], **kw)
    _check_straight(lanes["f", "g", 1], (59.3934, -19.2), (39.3934, -39.2), [S, C], **kw)
    _check_circle(lanes["g", "h", 0], (18.1, -18.1), 25, (315, 170), False, [C, N], 63.27, **kw)
    _check_circle(lanes["g", "h", 1], (18.1, -18.1), 30, (315, 165), False, [S, C], 78.54, **kw)
    _check_circle(lanes["h", "i", 0], (18.1, -18.1), 25, (170, 56), False, [C, N], 49.74, **kw)
    _check_circle(lanes["h", "i", 1], (18.1, -18.1), 30, (170, 58), False, [S, C], 58.64, **kw)
    _check_circle(lanes["i", "a", 0], (43.2, 23.4), 23.5, (240, 270), True, [C, S], 12.30, **kw)
    _check_circle(lanes["i", "a", 1], (43.2, 23.4), 18.5, (238, 268), True, [N, C], 9.69, **kw)
    assert len(lanes) == 18
    assert not make_oracle_env("racetrack").road.objects


# --------------------------------------------------------------------------------------------------
# Configuration and initial states (docs/scenarios.md)
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_config(scenario):
    env = make_oracle_env(scenario)
    freq = {"racetrack": 5}.get(scenario, 1)
    duration = {"racetrack": 40}.get(scenario, 20)
    assert (env.config["simulation_frequency"], env.config["policy_frequency"], env.config["duration"]) == (
        15, freq, duration)
    assert len(env.controlled_vehicles) == 2 and len(env.road.vehicles) == 2
    for obs_type in env.observation_type.agents_observation_types:
        assert obs_type.features == ["x", "y", "vx", "vy"] and obs_type.vehicles_count == 2
        assert obs_type.absolute and not obs_type.normalize and obs_type.see_behind
        assert not obs_type.include_obstacles
    types = env.action_type.agents_action_types
    assert [t.controlled_vehicle for t in types] == env.controlled_vehicles
    if scenario in ("merge", "roundabout"):
        speeds = {"merge": [20, 25, 30], "roundabout": [0, 4, 8, 12, 16]}[scenario]
        for v in env.controlled_vehicles:
            assert type(v).__name__ == "MDPVehicle"
            np.testing.assert_array_equal(v.target_speeds, speeds)
    else:
        for t, v in zip(types, env.controlled_vehicles):
            assert type(v).__name__ == "Vehicle" and not t.dynamical and t.size == 1
            assert (t.longitudinal, t.lateral) == ((True, False) if scenario == "intersection" else (False, True))
            assert tuple(t.acceleration_range) == (-5, 5) and tuple(t.steering_range) == (-np.pi / 4, np.pi / 4)
    if scenario == "intersection":
        assert env.config["offroad_terminal"]
    if scenario == "roundabout":  # the south car (follower) is appended to road.vehicles first
        assert env.road.vehicles == [env.controlled_vehicles[1], env.controlled_vehicles[0]]
    else:
        assert env.road.vehicles == env.controlled_vehicles


INITIAL = {  # docs/scenarios.md, initial states (intersection with the deterministic s = 61)
    "merge": [[70, 4, 25, 0, 70, 14.5, 25, 0], [70, 14.5, 25, 0, 70, 4, 25, 0]],
    "roundabout": [[-45, 2, 8, 0, 2, 85, 0, -8], [2, 85, 0, -8, -45, 2, 8, 0]],
    "intersection": [[2, 50, 0, -10, -50, 2, 10, 0], [-50, 2, 10, 0, 2, 50, 0, -10]],
    "racetrack": [[77, 0, 10, 0, 77, 5, 10, 0], [77, 5, 10, 0, 77, 0, 10, 0]],
}


@pytest.mark.parametrize("scenario", SCENARIOS)
def test_initial_observation(scenario):
    actions = np.zeros((1, 2), dtype=int if scenario in ("merge", "roundabout") else float)
    r = run_oracle(scenario, actions)
    assert r["obs"].dtype == np.float32 and r["obs"].shape == (2, 2, 8)
    np.testing.assert_allclose(r["obs"][0], INITIAL[scenario], atol=1e-5)


def test_initial_states_discrete():
    env = make_oracle_env("merge")
    leader, follower = env.controlled_vehicles
    assert leader.lane_index == ("a", "b", 1) and follower.lane_index == ("j", "k", 0)
    for v in env.controlled_vehicles:
        assert (v.heading, v.speed, v.target_speed, int(v.speed_index), v.route) == (0, 25, 25, 1, None)
    env = make_oracle_env("roundabout")
    leader, follower = env.controlled_vehicles
    assert leader.lane_index == ("wer", "wes", 0) and follower.lane_index == ("ser", "ses", 0)
    assert leader.lane.local_coordinates(leader.position)[0] == pytest.approx(125)
    assert follower.heading == pytest.approx(-np.pi / 2) and leader.heading == 0
    for v in env.controlled_vehicles:
        assert (v.speed, v.target_speed, int(v.speed_index)) == (8, 8, 2)
    assert [r[:2] for r in leader.route] == [("wer", "wes"), ("wes", "we"), ("we", "sx"), ("sx", "se"),
                                             ("se", "ex"), ("ex", "ee"), ("ee", "nx"), ("nx", "nxs")]
    assert [r[:2] for r in follower.route] == [("ser", "ses"), ("ses", "se"), ("se", "ex"), ("ex", "ee"),
                                               ("ee", "nx"), ("nx", "nxs")]


def test_intersection_start_offsets():
    env = make_oracle_env("intersection", leader_s=60.25, follower_s=62.5)
    leader, follower = env.controlled_vehicles
    np.testing.assert_allclose(leader.position, (2, 111 - 60.25))
    np.testing.assert_allclose(follower.position, (-111 + 62.5, 2))
    assert leader.heading == pytest.approx(-np.pi / 2) and follower.heading == pytest.approx(0)
    assert (leader.speed, follower.speed) == (10, 10) and not hasattr(leader, "route")
    # the fork's own draw 60 + N(1, 1), from env.np_random: reproducible through the reset seed
    a = run_oracle("intersection", np.zeros((1, 2)), seed=3, leader_s="random", follower_s="random")
    b = run_oracle("intersection", np.zeros((1, 2)), seed=3, leader_s="random", follower_s="random")
    np.testing.assert_array_equal(a["obs"][0], b["obs"][0])
    assert a["y"][0, 0] != 50.0


# --------------------------------------------------------------------------------------------------
# Verified roll-outs
# --------------------------------------------------------------------------------------------------


def test_merge_idle_idle():  # a constant-action roll-out checked against highway-env, case 1
    r = _run("merge", IDLE, IDLE)
    assert r["length"] == 12 and r["done"][-1] and not r["done"][:-1].any()
    # follower hits the obstacle during decision 10, at x = 306.5 on the merge lane (b,c,2)
    assert _first(r["crashed"][:, 1]) == 10 and not r["crashed"][:, 0].any()
    assert r["x"][10, 1] == pytest.approx(306.5, abs=1e-3)
    # leader crosses x > 350 at t = 12 (+2 +10)
    assert _first(r["x"][:, 0] > 350) == 12
    assert r["terminated"][:, 0].tolist() == [False] * 11 + [True]
    assert r["terminated"][:, 1].tolist() == [False] * 9 + [True] * 3
    np.testing.assert_array_equal(r["reward"][:, 0], [2] * 11 + [12])
    np.testing.assert_array_equal(r["reward"][:, 1], [2] * 9 + [-3] * 3)
    np.testing.assert_array_equal(r["reward"].sum(0), [34, 9])
    np.testing.assert_array_equal(r["cost"][:, 1], [0] * 9 + [5] * 3)
    assert not r["cost"][:, 0].any()
    # info arrival flags are zeroed on any crash; the env's one-shot flag is set
    assert not r["arrived"].any() and r["arrived_flag"][-1].tolist() == [True, False]
    assert r["first_arrived"][-1] == 1


def test_merge_faster_faster():  # a constant-action roll-out checked against highway-env, case 2
    r = _run("merge", FASTER, FASTER)
    assert r["length"] == 9
    assert _first(r["crashed"][:, 1]) == 8  # follower into the obstacle at t = 8
    assert _first(r["crashed"][:, 0]) == 9  # leader (lane 1, x ~ 307 at t = 8) into the displaced follower
    assert r["lane"][8, 0] == 3 and r["x"][8, 0] == pytest.approx(307, abs=0.01)  # lane 3 = (b, c, 1)
    assert r["crash"][-1] and r["terminated"][-1].all()
    # derived from merge's reward (docs/scenarios.md): +2 while target index >= 1, -5 per crashed step
    np.testing.assert_array_equal(r["reward"].sum(0), [8 * 2 - 3, 7 * 2 - 3 - 3])


def test_merge_faster_lane_left():  # a constant-action roll-out checked against highway-env, case 3
    r = _run("merge", FASTER, LANE_LEFT)
    lanes = [f"{f}-{t}-{i}" for f, t, i, _ in oracle_lanes("merge")]
    follower_lanes = [lanes[k] for k in r["lane"][:, 1]]
    visited = [lane for i, lane in enumerate(follower_lanes) if i == 0 or lane != follower_lanes[i - 1]]
    assert visited[:5] == ["j-k-0", "k-b-0", "b-c-2", "b-c-1", "b-c-0"]  # merges (b,c,2) -> 1 -> 0
    assert r["length"] == 12 and not r["crash"].any() and not r["crashed"].any()
    assert _first(r["arrived"][:, 0]) == 9 and _first(r["arrived"][:, 1]) == 11  # t = 10 and t = 12
    np.testing.assert_array_equal(r["reward"][:, 0], [2] * 9 + [12, 2, 2])
    np.testing.assert_array_equal(r["reward"][:, 1], [2] * 11 + [7])
    np.testing.assert_array_equal(r["reward"].sum(0), [34, 29])
    assert r["first_arrived"][-1] == 1 and r["speed"][10, 0] == pytest.approx(30, abs=1e-3)


def test_roundabout_idle_idle():  # a constant-action roll-out checked against highway-env, case 1
    r = _run("roundabout", IDLE, IDLE)
    assert r["length"] == 8
    assert _first(r["crashed"][:, 0]) == 8 and _first(r["crashed"][:, 1]) == 8  # mutual crash at t = 8
    assert r["x"][8, 0] == pytest.approx(9, abs=1) and r["y"][8, 0] == pytest.approx(21, abs=1)  # near (9, 21)
    np.testing.assert_array_equal(r["reward"], [[0, 0]] * 7 + [[-5, -5]])  # 8 m/s is outside [10, 15]
    np.testing.assert_array_equal(r["cost"][-1], [5, 5])


def test_roundabout_faster_faster():  # a constant-action roll-out checked against highway-env, case 2
    r = _run("roundabout", FASTER, FASTER)
    assert r["length"] == 5 and _first(r["crash"]) == 4  # crash at t = 5
    assert (r["speed"][4] > 15.9).all() and (r["target_speed"][4] == 16).all()  # both ~16 m/s
    assert r["crashed"][5].all()


def test_roundabout_faster_idle():  # a constant-action roll-out checked against highway-env, case 3
    r = _run("roundabout", FASTER, IDLE)
    assert r["length"] == 20 and not r["crash"].any()
    assert _first(r["arrived"][:, 0]) == 10  # leader arrives at t = 11 ...
    assert r["arrived"][10:, 0].all() and not r["arrived"][:, 1].any()
    assert r["terminated"][:, 1].tolist() == [False] * 19 + [True]  # ... follower still driving: time-out
    assert r["time"][-1] == 20
    np.testing.assert_array_equal(r["reward"].sum(0), [52, 0])
    np.testing.assert_array_equal(r["reward"][:, 0], [2] + [0] * 9 + [5] * 10)
    # both ride the outer ring lane (id 1)
    lanes = [(f, t, i) for f, t, i, _ in oracle_lanes("roundabout")]
    for k in r["lane"].ravel():
        f, t, i = lanes[k]
        assert i == 0 or (f, t) in {("se", "ex"), ("ex", "ee"), ("ee", "nx"), ("nx", "ne"), ("ne", "wx"),
                                    ("wx", "we"), ("we", "sx"), ("sx", "se")}


def test_intersection_constant_speed():  # a = 0
    r = _run("intersection", 0.0, 0.0)
    assert r["length"] == 5 and _first(r["crash"]) == 4  # crash in the middle at t = 5
    np.testing.assert_array_equal(r["reward"], [[2, 2]] * 4 + [[-3, -3]])
    np.testing.assert_array_equal(r["cost"][-1], [5, 5])
    assert r["crashed"][5].all() and r["terminated"][-1].all()
    assert not r["arrived"].any() and r["first_arrived"][-1] == 0


def test_intersection_leader_fast_follower_reverse():  # leader a = +1, follower a = -1
    r = _run("intersection", 1.0, -1.0)
    assert r["length"] == 8 and not r["crash"].any()
    assert _first(r["arrived"][:, 0]) == 3 and r["first_arrived"][3] == 1  # leader arrives first at t = 4
    assert r["reward"][3, 0] == 5 and r["reward"][:, 0].sum() == 5  # +5 first, no speed reward above 12
    assert r["speed"][:, 0].max() == pytest.approx(40)
    assert _first(~r["on_road"][:, 1]) == 8  # follower reverses off the road at t = 8
    assert r["terminated"][:, 1].tolist() == [False] * 7 + [True]
    assert r["speed"][8, 1] < 0 and not r["arrived"][:, 1].any()


def test_racetrack_steering_zero():  # steering 0 for both
    r = _run("racetrack", 0.0, 0.0, steps=200)
    assert r["length"] == 21  # episode over at step 21, x = 119
    assert _first(~r["on_road"][:, 0]) == 21 and r["x"][21, 0] == pytest.approx(119)
    # docs/scenarios.md says both cars drive off the first curve at step 21; both are off-road then, but the follower
    # (outer lane, y = 5) already left the road at step 18 (x = 113) and the episode waits for the leader.
    assert _first(~r["on_road"][:, 1]) == 18 and r["x"][18, 1] == pytest.approx(113)
    np.testing.assert_allclose(r["speed"], 10)
    np.testing.assert_allclose(r["heading"], 0)
    assert r["reward"][:11].tolist() == [[1.0, 1.0]] * 11  # centred, zero steering: the maximum 1 per step
    np.testing.assert_array_equal(r["cost"][-1], [0.5, 0.5])
    assert r["reward"][-1].tolist() == [0, 0] and not r["crash"].any()


def test_racetrack_steering_positive():  # a = +0.3 for both
    r = _run("racetrack", 0.3, 0.3, steps=200)
    assert r["length"] == 9 and r["terminated"][-1].all()
    assert _first(~r["on_road"][:, 0]) == 9 and _first(~r["on_road"][:, 1]) == 5
    np.testing.assert_allclose(r["sub_steering"], 0.3 * np.pi / 4)


def test_racetrack_reward_formula():  # on the first step: centred, steering 0.3
    r = _run("racetrack", 0.3, 0.3, steps=200)
    env = make_oracle_env("racetrack")
    env.step((np.array([0.3]), np.array([0.3])))
    v = env.controlled_vehicles[0]
    _, lat = v.lane.local_coordinates(v.position)
    assert r["reward"][0, 0] == pytest.approx((1 / (1 + 4 * lat**2) - 0.3 * 0.3 + 1) / 2, abs=1e-12)


def test_racetrack_time_limit():  # time 40.00000000000003 >= 40 at the 200th decision
    env = make_oracle_env("racetrack")
    for _ in range(199):
        env.time += 1 / 5
    assert env.time < 40
    env.time += 1 / 5
    assert env.time == 40.00000000000003


# --------------------------------------------------------------------------------------------------
# Record consistency (what the JAX parity tests rely on)
# --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("scenario", "actions"), [("merge", (FASTER, LANE_LEFT)), ("roundabout", (FASTER, FASTER)),
                                                   ("intersection", (1.0, -1.0)), ("racetrack", (0.3, 0.3))])
def test_records_consistent(scenario, actions):
    r = _run(scenario, *actions, steps=200 if scenario == "racetrack" else 20)
    T, F = r["length"], r["frames"]
    assert F == (3 if scenario == "racetrack" else 15)
    for key in ("x", "y", "heading", "speed", "crashed", "on_road", "lane"):
        assert r[key].shape == (T + 1, 2)
        assert r["sub_" + key].shape == (T * F, 2)
        # the state after a decision is the state after its last substep
        np.testing.assert_array_equal(r[key][1:], r["sub_" + key][F - 1::F])
    for key in ("reward", "cost", "terminated", "arrived"):
        assert r[key].shape == (T, 2)
    assert r["obs"].shape == (T + 1, 2, 8) and r["done"].shape == (T,) and r["crash"].shape == (T,)
    assert r["terminated"].dtype == bool and r["lane"].dtype == np.int64
    assert ("target_lane" in r) == (scenario in ("merge", "roundabout"))
    # observation = [self; other] x [x, y, vx, vy] built from the vehicle states
    own = np.stack([r["x"], r["y"], r["speed"] * np.cos(r["heading"]), r["speed"] * np.sin(r["heading"])], -1)
    np.testing.assert_allclose(r["obs"][:, :, :4], own.astype(np.float32), rtol=1e-6, atol=1e-4)
    # the other vehicle is observed iff it is closer than PERCEPTION_DISTANCE = 200 m, else zeros
    seen = np.hypot(r["x"][:, 0] - r["x"][:, 1], r["y"][:, 0] - r["y"][:, 1]) < 200
    np.testing.assert_array_equal(r["obs"][seen, 0, 4:], r["obs"][seen, 1, :4])
    np.testing.assert_array_equal(r["obs"][seen, 1, 4:], r["obs"][seen, 0, :4])
    assert not r["obs"][~seen][:, :, 4:].any()
    np.testing.assert_array_equal(r["crash"], r["crashed"][1:].any(1))
    np.testing.assert_array_equal(r["done"], r["terminated"].all(1))


def test_continuous_action_shapes_equivalent():
    a = np.tile([[0.5, -0.25]], (6, 1))
    r2 = run_oracle("intersection", a)
    r3 = run_oracle("intersection", a[:, :, None])
    for key in ("x", "y", "speed", "reward"):
        np.testing.assert_array_equal(r2[key], r3[key])
    assert r2["length"] == 6  # actions ran out before the episode ended


def test_merge_obstacle_not_observed():
    """include_obstacles=False: the follower next to the obstacle still observes the leader (docs/scenarios.md,
    Observation)."""
    r = _run("merge", IDLE, IDLE)
    np.testing.assert_allclose(r["obs"][9:, 1, 4:6], np.stack([r["x"][9:, 0], r["y"][9:, 0]], -1), atol=1e-4)


def test_speed_guard_clip_persists_within_decision():
    """highway-env detail a reimplementation must copy (kinematics.py ``clip_actions``).

    The ±40 m/s guard overwrites the *stored* action dict of a plain Vehicle, and that dict is only
    replaced at the next decision: once clipped, the acceleration stays at the clipped value for the
    remaining substeps of the decision, even after the speed has dropped back below 40.
    """
    r = run_oracle("intersection", np.tile([0.7, -0.5], (20, 1)))  # leader: 3.5 m/s^2 from 10 m/s
    F = r["frames"]
    speed, acc = r["sub_speed"][:, 0], r["sub_acceleration"][:, 0]
    k = _first(speed > 40)  # the substep that first crosses 40 m/s (with a = 3.5)
    assert acc[k] == 3.5 and k // F == 8
    assert acc[k + 1] == pytest.approx(40 - speed[k])  # clipped on the next substep ...
    np.testing.assert_array_equal(acc[k + 1:(k // F + 1) * F], acc[k + 1])  # ... and kept to the decision's end
    nxt = slice((k // F + 1) * F, (k // F + 2) * F)  # next decision: clipped once, then constant
    assert (acc[nxt] == acc[nxt][0]).all() and acc[nxt][0] < 0 and speed[nxt][-1] < 40
