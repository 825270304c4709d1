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

from tests.traffic_oracle import oracle_config, run_oracle
from tests.traffic_utils import run_jax

POS_TOL = 1e-6
DURATION = {"highway-v0": 40, "highway-fast-v0": 30}


def check_episode(name, k, seed, steps):
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
    err = 0.0
    for key in ("x", "y", "heading", "speed"):
        e = np.abs(o["frames"][key] - j["frames"][key][:, alive])
        err = max(err, float(e.max()))
        assert e.max() <= POS_TOL, (key, float(e.max()), int(np.argmax(e.max(1) > POS_TOL)))
    for key in ("crashed", "lane", "target_lane"):
        np.testing.assert_array_equal(j["frames"][key][:, alive], o["frames"][key], err_msg=key)
    np.testing.assert_allclose(j["obs"].astype(np.float32), o["obs"], rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(j["reward"], o["reward"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(o["env_reward"], o["reward"][:, 0], rtol=0, atol=0)  # agent 0 is highway-env's
    np.testing.assert_array_equal(j["terminated"], o["terminated"])
    np.testing.assert_array_equal(j["truncated"], o["truncated"])
    tl = o["frames"]["target_lane"]
    return err, int((tl[1:] != tl[:-1]).sum()), int(o["frames"]["crashed"][-1].sum())


@pytest.mark.parametrize("name,k,seed,steps", [("highway-fast-v0", 1, 0, 12), ("highway-v0", 3, 1, 5)])
def test_parity_sample(name, k, seed, steps, x64):
    err, changes, crashes = check_episode(name, k, seed, steps)
    print(f"\n{name} K={k}: max position error {err:.1e} m, {changes} lane-change decisions, {crashes} crashed")
    assert changes > 0


@pytest.mark.slow
@pytest.mark.parametrize("name", ["highway-v0", "highway-fast-v0"])
@pytest.mark.parametrize("k", [1, 3])
def test_parity_full(name, k, x64):
    """30 random-action episodes per configuration, full duration (ends at the first ``done``)."""
    errs, changes, crashes = [], 0, 0
    for seed in range(30):
        e, c, x = check_episode(name, k, 100 + seed, DURATION[name])
        errs.append(e)
        changes += c
        crashes += x
    print(f"\n{name} K={k}: 30 episodes, worst position error {max(errs):.1e} m, "
          f"{changes} lane-change decisions, {crashes} vehicles crashed at the end")
