"""Parity of the traffic tasks (highway-v0, highway-fast-v0) with highway-env, K = 1 and K = 3 agents.

highway-env runs its own task from the JAX initial state (tests/traffic_oracle.py); after every
simulation frame every vehicle's x, y, heading, speed, crashed, lane and target lane are compared,
after every step the observations, per-agent rewards and terminations. Under x64 positions agree
to 1e-6 m with identical discrete events. The default suite runs a short sample; the full sets
(30 random-action episodes per configuration, full duration) are ``@pytest.mark.slow``.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.traffic_oracle import arcsin_one_ulp_off, oracle_config, run_oracle
from tests.traffic_utils import run_jax

POS_TOL = 1e-6
DURATION = {"highway-v0": 40, "highway-fast-v0": 30}
# highway-env's one-ulp nudges for a chaotic episode: (steering arcsin up/down/exact, initial field, direction)
NUDGES = ((1, None, 0), (-1, None, 0), (0, "x", 1), (0, "x", -1), (0, "y", 1), (0, "y", -1), (0, "speed", 1),
          (0, "speed", -1))
# the nudged runs sample highway-env's spread (more nudges widen it): the error may exceed their largest distance
# by this factor
SPREAD_SLACK = 1.1


def check_episode(name, k, seed, steps):
    """One random-action episode, everything asserted; returns (max position error, lane-change decisions,
    crashed vehicles at the end, highway-env's one-ulp spread where it was needed).

    A chaotic episode (a driver near zero speed, whose steering amplifies an ulp without bound) may exceed
    ``POS_TOL``: its error must then stay within the spread of highway-env's own runs under one-ulp nudges
    (``NUDGES``: its steering arcsin one ulp up or down, or every initial x, y or speed one ulp up or down; the
    largest distance between any two of those runs and the exact one, times ``SPREAD_SLACK``, must cover the
    error), and everything is compared exactly up to the first frame where a nudged run departs from
    highway-env's own by more than ``POS_TOL`` (beyond it highway-env itself is not determined to that). Nudges
    are added until both hold, so the JAX run may not depart before every nudged run does."""
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, 5, size=(steps, k))
    j = run_jax(name, seed, actions, controlled_vehicles=k)
    env = j["env"]
    o = run_oracle(name, j["init"], env.controlled, actions[: j["length"]], oracle_config(name, k))
    alive = j["init"]["alive"]
    # highway-env's own lane-change timers from the injected positions
    np.testing.assert_allclose(o["timers"], j["init"]["timer"][alive & env.is_idm], rtol=0, atol=1e-12)
    n = j["length"] * env.frames
    assert len(o["frames"]["x"]) == n
    gap = lambda a, b, m: np.maximum(*(np.abs(a["frames"][q][:m] - b[q][:m]).max(1) for q in ("x", "y")))  # per frame
    off = gap(o, {q: j["frames"][q][:, alive] for q in ("x", "y")}, n)
    err = float(off.max())
    spread = None
    if err > POS_TOL:
        departs = int(np.argmax(off > POS_TOL))  # the JAX run's first frame over the tolerance
        spread, horizon, runs = 0.0, n, [o]
        for nudge, field, direction in NUDGES:
            init = dict(j["init"])
            if field:
                init[field] = np.nextafter(np.asarray(init[field]), direction * np.inf)
            with arcsin_one_ulp_off(nudge):
                moved = run_oracle(name, init, env.controlled, actions[: j["length"]], oracle_config(name, k))
            m = min(n, len(moved["frames"]["x"]))
            apart = gap(o, moved["frames"], m)
            horizon = min(horizon, int(np.argmax(apart > POS_TOL)) if apart.max() > POS_TOL else m)
            # the largest distance between any two of highway-env's runs so far
            spread = max([spread] + [float(gap(r, moved["frames"], min(m, len(r["frames"]["x"]))).max())
                                               for r in runs])
            runs.append(moved)
            # done once the spread covers the error and a nudged run departs no later than the JAX run does
            if err <= SPREAD_SLACK * spread + POS_TOL and horizon <= departs:
                break
        # highway-env's own spread under one-ulp nudges bounds the error (the error may equal it: a nudged run can
        # take the very branch the JAX run takes)
        assert err <= SPREAD_SLACK * spread + POS_TOL, (
            f"{name} K={k} seed {seed}: position error {err:.9g} m exceeds {POS_TOL} m and {SPREAD_SLACK} x "
            f"highway-env's own one-ulp spread {spread:.9g} m")
        n = horizon
    for key in ("x", "y", "heading", "speed"):
        e = np.abs(o["frames"][key][:n] - j["frames"][key][:n, alive])
        assert e.max(initial=0.0) <= POS_TOL, (key, float(e.max()), int(np.argmax(e.max(1) > POS_TOL)))
    for key in ("crashed", "lane", "target_lane"):
        np.testing.assert_array_equal(j["frames"][key][:n, alive], o["frames"][key][:n], err_msg=key)
    last = n // env.frames  # the steps whose frames all agree
    np.testing.assert_allclose(j["obs"][:last].astype(np.float32), o["obs"][:last], rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(j["reward"][:last], o["reward"][:last], rtol=0, atol=1e-9)
    np.testing.assert_allclose(o["env_reward"], o["reward"][:, 0], rtol=0, atol=0)  # agent 0 is highway-env's
    np.testing.assert_array_equal(j["terminated"][:last], o["terminated"][:last])
    np.testing.assert_array_equal(j["truncated"][:last], o["truncated"][:last])
    tl = o["frames"]["target_lane"]
    return err, int((tl[1:] != tl[:-1]).sum()), int(o["frames"]["crashed"][-1].sum()), spread


@pytest.mark.parametrize("name,k,seed,steps", [("highway-fast-v0", 1, 0, 12), ("highway-v0", 3, 1, 5)])
def test_parity_sample(name, k, seed, steps, x64):
    err, changes, crashes, _ = check_episode(name, k, seed, steps)
    print(f"\n{name} K={k}: max position error {err:.1e} m, {changes} lane-change decisions, {crashes} crashed")
    assert changes > 0


@pytest.mark.slow
@pytest.mark.parametrize("name", ["highway-v0", "highway-fast-v0"])
@pytest.mark.parametrize("k", [1, 3])
def test_parity_full(name, k, x64):
    """30 random-action episodes per configuration, full duration (ends at the first ``done``)."""
    errs, changes, crashes, chaotic = [], 0, 0, []
    for seed in range(30):
        e, c, x, spread = check_episode(name, k, 100 + seed, DURATION[name])
        errs.append(e)
        changes += c
        crashes += x
        if spread is not None:
            chaotic.append(f"seed {100 + seed}: {e:.1e} m vs {spread:.1e} m")
    print(f"\n{name} K={k}: 30 episodes, worst position error {max(errs):.1e} m, "
          f"{changes} lane-change decisions, {crashes} vehicles crashed at the end; {len(chaotic)} episodes over "
          f"{POS_TOL:g} m, each within highway-env's own one-ulp spread ({', '.join(chaotic) or '-'})")
