"""Parity of intersection-v0 / intersection-multi-agent-v0 with highway-env, the JAX draws injected.

highway-env runs its own intersection (tests/intersection_oracle.py) with every random number
the JAX episode drew (initial vehicles, challenger, agents, each step's spawn: position,
speed, route, driver exponent). After every simulation frame the set of alive vehicles and
each one's x, y, heading, speed, crashed flag, lane, yielding flag and target speed are
compared; the spawn and clear events, the observations, per-agent rewards and terminations
after every step. Under x64 positions agree to 1e-6 m with identical events. The default
suite runs a short sample; the full sets (30+ random-action episodes per K at the full
duration) are ``@pytest.mark.slow``.
"""

from __future__ import annotations

import numpy as np
import pytest

from envs_jax.scenarios import intersection_continuous as v1
from tests.intersection_oracle import oracle_config, run_oracle
from tests.intersection_utils import reset_records, run_jax, step_records

POS_TOL = 1e-6
# The agents' target-speed grid in the parity runs (both sides). With highway-env's default grid
# (0, 4.5, 9) an agent can be told to stop, and below about 0.5 m/s highway-env's steering controller
# (heading command ~ lateral offset / speed) amplifies rounding differences five- to tenfold per frame
# (docs/parity.md, "intersection-v0 with traffic"); a grid starting at 3 m/s keeps every agent in the
# well-conditioned regime while the IDM drivers still stop, yield and queue.
TARGET_SPEEDS = [3.0, 6.0, 9.0]


def action_config(k, target_speeds=TARGET_SPEEDS):
    action = {"type": "DiscreteMetaAction", "longitudinal": True, "lateral": False,
              "target_speeds": list(target_speeds)}
    return action if k == 1 else {"type": "MultiAgentAction", "action_config": action}


# intersection-v1: the band of random target speeds of the agents. Below about 3.7 m/s highway-env's 15 Hz
# Runge-Kutta step is outside its stability region for the BicycleVehicle's yaw-rate mode (eigenvalue
# -155 / speed 1/s), so it multiplies last-bit differences up to hundreds of times per frame (docs/parity.md,
# "intersection-v1"); speeds from 5 m/s keep both sides in the stable regime.
V1_SPEEDS = (5.0, 15.0)


def v1_actions(rng, steps, k):
    """Random ``[acceleration, steering]`` per agent and step: steering uniform in ``[-1, 1]``; acceleration
    towards a speed drawn uniformly in :data:`V1_SPEEDS` each step (at most full throttle or brake), so the
    agents' speed (10 m/s at the start, ``+ 5 a`` m/s per step) stays in the band while they are not crashed."""
    target = rng.uniform(*V1_SPEEDS, size=(steps, k))
    acc = np.zeros((steps, k))
    speed = np.full(k, 10.0)
    for t in range(steps):
        acc[t] = np.clip((target[t] - speed) / 5.0, -1.0, 1.0)
        speed = speed + 5.0 * acc[t]
    return np.stack([acc, rng.uniform(-1.0, 1.0, size=(steps, k))], axis=-1)


# Observation rows are sorted by the distance along the observer's lane (highway-env's ``lane_distance_to``);
# two vehicles whose distances differ by less than this are a tie that last-bit rounding decides, and either
# order is highway-env's behaviour (docs/parity.md, "intersection-v1").
TIE_TOL = 1e-9  # m


def _normalised_positions(env, x, y, observer):
    """Every vehicle's ``(x, y)`` as an observation row of ``observer`` would show it (normalised and clipped as the
    Kinematics config says; relative to the observer unless absolute)."""
    cfg = env.obs_config
    ranges = dict(cfg.features_range)
    out = []
    for name, v in (("x", x), ("y", y)):
        v = np.asarray(v, np.float64) - (0.0 if cfg.absolute else float(observer[len(out)]))
        lo, hi = ranges[name]
        if cfg.normalize:
            v = -1.0 + 2.0 * (v - lo) / (hi - lo)
            v = np.clip(v, -1.0, 1.0) if cfg.clip else v
        out.append(v)
    return np.stack(out, -1)


def compare_observations(j, o_obs):
    """The observations of every step, row by row. A row may differ only where the two sides order a near-tie
    differently: the vehicles each side can have put there (those whose normalised position is the row's) must
    include two different vehicles at the same distance along the observer's lane within :data:`TIE_TOL`,
    highway-env's sort key (the tie can also decide which of two vehicles takes the last row); the same vehicle
    shown differently fails. Returns the number of such rows."""
    from envs_jax import lanes as L

    env = j["env"]
    cfg = env.obs_config
    ix, iy = cfg.features.index("x"), cfg.features.index("y")
    jo, oo = j["obs"].astype(np.float32), np.asarray(o_obs, np.float32)
    assert jo.shape == oo.shape
    same = np.isclose(jo, oo, rtol=1e-6, atol=1e-5).all(-1)  # [steps + 1, K, rows]
    ties = 0
    for t, a, r in zip(*np.nonzero(~same)):
        if t == 0:
            x, y, lane, alive = (np.asarray(getattr(j["st0"], k)) for k in ("x", "y", "lane", "alive"))
        else:  # the observation is taken at the step's last frame, before clears and spawns
            f = t * env.frames - 1
            x, y, lane, alive = (j["frames"][k][f] for k in ("x", "y", "lane", "alive"))
        me = env.controlled[a]
        shown = _normalised_positions(env, x, y, (x[me], y[me]))
        s_me = float(L.local_coordinates(env.road.lanes, int(lane[me]), x[me], y[me])[0])

        def keys(row):
            near = alive & (np.abs(shown - row[[ix, iy]]).max(-1) < 5e-5)
            assert near.any(), (t, a, r, "an observation row matches no vehicle", row)
            return {int(i): abs(float(L.local_coordinates(env.road.lanes, int(lane[me]), x[i], y[i])[0]) - s_me)
                    for i in np.flatnonzero(near)}

        # two different vehicles at (nearly) the same key; one vehicle shown differently is a real mismatch
        kj, ko = keys(jo[t, a, r]), keys(oo[t, a, r])
        gap = min([abs(kj[i] - ko[k]) for i in kj for k in ko if i != k] + [np.inf])
        assert gap <= TIE_TOL, (t, a, r, "rows differ beyond a near-tie", gap, jo[t, a, r], oo[t, a, r])
        ties += 1
    return ties


def frame_table(o_frame, key):
    return dict(zip(o_frame["slot"], o_frame[key]))


def compare_vehicles(o_frame, j_values, j_alive, where):
    slots = sorted(o_frame["slot"])
    assert slots == sorted(np.nonzero(j_alive)[0].tolist()), (where, slots, np.nonzero(j_alive)[0].tolist())
    err = 0.0
    extra = ("lateral_speed", "yaw_rate") if "lateral_speed" in j_values else ()  # intersection-v1's agents
    for key in ("x", "y", "heading", "speed", "target_speed") + extra:
        o = frame_table(o_frame, key)
        e = max([abs(o[s] - j_values[key][s]) for s in slots] + [0.0])
        assert e <= POS_TOL, (where, key, e)
        if key in ("x", "y"):
            err = max(err, e)
    for key in ("crashed", "lane", "yielding"):
        o = frame_table(o_frame, key)
        bad = [s for s in slots if o[s] != j_values[key][s]]
        assert not bad, (where, key, bad)
    return err


def check_episode(k, seed, steps, name=None, num_slots=None, keep=False, **overrides):
    """One random-action episode (``steps`` decisions, cut at the first ``done``) on both sides; ``overrides``
    are highway-env config keys given to both, ``num_slots`` the JAX pool size. ``intersection-v1``:
    :func:`v1_actions`."""
    name = name or ("intersection-v0" if k == 1 else "intersection-multi-agent-v0")
    continuous = name == v1.NAME
    rng = np.random.default_rng(seed)
    if continuous:
        actions = v1_actions(rng, steps, k)
        if k > 1:  # highway-env's ContinuousIntersectionEnv with its sections wrapped for several agents
            overrides.setdefault("action", {"type": "MultiAgentAction", "action_config": dict(v1.ACTION)})
            overrides.setdefault("observation", {"type": "MultiAgentObservation",
                                                 "observation_config": dict(v1.OBSERVATION)})
    else:
        actions = rng.integers(0, 3, size=(steps, k))
        overrides.setdefault("action", action_config(k))
    pool = {} if num_slots is None else {"num_slots": num_slots}
    j = run_jax(name, seed, actions, controlled_vehicles=k, **overrides, **pool)
    env = j["env"]
    T = j["length"]
    init_recs, step_recs = reset_records(j), step_records(j)
    o = run_oracle(k, init_recs, j["draws"]["z_ego"], j["draws"]["destination"], step_recs[:T], actions[:T],
                   oracle_config(k, **overrides), continuous=continuous)
    # the reset: same spawn decisions, same vehicles after warm-up, challenger and agents
    assert o["init_spawns"] == [r["spawned"] and not r["pool_full"] for r in init_recs]
    st0 = j["st0"]
    init_vals = {key: np.asarray(getattr(st0, key)) for key in ("x", "y", "heading", "speed", "crashed", "lane",
                                                                  "yielding", "target_speed")}
    err = compare_vehicles(o["init"], init_vals, np.asarray(st0.alive), "reset")
    # every frame
    n = T * env.frames
    assert len(o["frames"]) == n
    jf = j["frames"]
    yields = 0
    for f in range(n):
        vals = {key: jf[key][f] for key in jf}
        err = max(err, compare_vehicles(o["frames"][f], vals, jf["alive"][f], f"frame {f}"))
        yields += int(np.sum(jf["yielding"][f] & jf["alive"][f]))
    # after each step: clears and spawns leave the same vehicles
    assert o["spawns"][len(init_recs):] == [r["spawned"] and not r["pool_full"] for r in step_recs[:T]]
    for t in range(T):
        assert o["after_step"][t] == np.nonzero(j["alive"][t])[0].tolist(), t
    ties = compare_observations(j, o["obs"])
    np.testing.assert_allclose(j["reward"], o["reward"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(o["env_reward"], o["reward"].mean(1), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(j["terminated"], o["terminated"])
    np.testing.assert_array_equal(j["env_terminated"], o["env_terminated"])
    np.testing.assert_array_equal(j["truncated"], o["truncated"])
    spawns = int(sum(r["spawned"] for r in step_recs[:T]))
    crashed = int(jf["crashed"][-1].sum())
    out = dict(err=err, yields=yields, spawns=spawns, crashed=crashed, steps=T, max_vehicles=o["max_vehicles"],
               skipped=int(j["skipped"][-1]), pool_skips=len(o["pool_skips"]), ties=ties)
    return (out, j, o) if keep else out


def test_parity_sample_small_pool(x64):
    """Two agents, a pool of 10 slots (the default holds 25): spawns that find no free slot are skipped and
    counted (in the reset and during the episode); highway-env, told to drop the same spawns, then agrees on
    every vehicle of every frame, so nothing else changed and no live vehicle was overwritten."""
    r = check_episode(2, 5, 13, num_slots=10)
    print(f"\nK=2, 10 slots: {r}")
    assert r["skipped"] > 0 and r["skipped"] == r["pool_skips"]


@pytest.mark.slow
@pytest.mark.parametrize("k", [1, 2, 4])
def test_parity_full(k, x64):
    """30 random-action episodes per K at the full duration (13 s; cut at the first ``done``)."""
    rows = [check_episode(k, 200 + seed, 13) for seed in range(30)]
    summary = {key: sum(r[key] for r in rows) for key in ("yields", "spawns", "crashed", "steps", "skipped",
                                                           "ties")}
    print(f"\nK={k}: 30 episodes, worst position error {max(r['err'] for r in rows):.1e} m, "
          f"most vehicles at once {max(r['max_vehicles'] for r in rows)}, totals {summary}")
    assert summary["skipped"] == 0 and summary["yields"] > 0 and summary["spawns"] > 0


@pytest.mark.slow
def test_parity_small_pool_full():
    """Ten episodes with a pool far too small (K + 6 slots): every skip reported, everything else equal."""
    import jax

    with jax.enable_x64(True):
        rows = [check_episode(1, 300 + seed, 13, num_slots=7) for seed in range(10)]
    assert sum(r["skipped"] for r in rows) > 0
    assert all(r["skipped"] == r["pool_skips"] for r in rows)


def test_parity_v1_sample(x64):
    """intersection-v1, two dynamical agents, a few random continuous steps (:func:`v1_actions`): every vehicle
    of every frame (the agents' lateral speed and yaw rate included), events, observations and rewards as
    highway-env."""
    r, j, o = check_episode(2, 11, 4, name=v1.NAME, keep=True)
    print(f"\nintersection-v1 K=2: {r}")
    assert r["steps"] >= 1 and r["ties"] == 0
    # the tie-tolerant comparison still fails on a real difference: a vehicle's speed, or two rows swapped whose
    # vehicles lie at clearly different distances
    obs = np.array(o["obs"])
    obs[1, 0, 1, 3] += 0.01
    with pytest.raises(AssertionError, match="rows differ beyond a near-tie"):
        compare_observations(j, obs)
    obs = np.array(o["obs"])
    obs[1, 0, [1, 2]] = obs[1, 0, [2, 1]]
    with pytest.raises(AssertionError, match="rows differ beyond a near-tie"):
        compare_observations(j, obs)


@pytest.mark.slow
@pytest.mark.parametrize("k", [1, 2, 4])
def test_parity_v1_full(k, x64):
    """intersection-v1: 30 episodes per K with random continuous actions (:func:`v1_actions`) at the full
    duration (cut at the first ``done``)."""
    rows = [check_episode(k, 400 + seed, 13, name=v1.NAME) for seed in range(30)]
    summary = {key: sum(r[key] for r in rows) for key in ("yields", "spawns", "crashed", "steps", "skipped",
                                                           "ties")}
    print(f"\nintersection-v1 K={k}: 30 episodes, worst position error {max(r['err'] for r in rows):.1e} m, "
          f"most vehicles at once {max(r['max_vehicles'] for r in rows)}, totals {summary}")
    assert summary["skipped"] == 0 and summary["spawns"] > 0
