"""``regulation.conflicts`` against highway-env's own ``RegulatedRoad.is_conflict_possible`` test, pair by pair.

The predictions are random and clustered (a few metres apart, random headings), so most pairs pass the
bounding-circle pre-check at some time and the rectangle test decides; both the plain call (every pair tested)
and the batched one (``vmap``, where the rectangle tests run only on the packed candidate pairs) must equal the
brute force.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from envs_jax import regulation
from envs_jax import vehicle as Veh

utils = pytest.importorskip("highway_env.utils")


def brute_force(px, py, ph, alive):
    """highway-env's pre-check and rectangle test for every pair of live slots, at every prediction time."""
    n = len(px)
    out = np.zeros((n, n), bool)
    for i in range(n):
        for j in range(i + 1, n):
            if not (alive[i] and alive[j]):
                continue
            for t in range(px.shape[1]):
                p1, p2 = np.array([px[i, t], py[i, t]]), np.array([px[j, t], py[j, t]])
                if np.linalg.norm(p2 - p1) > Veh.LENGTH:
                    continue
                if utils.rotated_rectangles_intersect(
                        (p1, 1.5 * Veh.LENGTH, 0.9 * Veh.WIDTH, ph[i, t]),
                        (p2, 1.5 * Veh.LENGTH, 0.9 * Veh.WIDTH, ph[j, t])):
                    out[i, j] = out[j, i] = True
                    break
    return out


def predictions(rng, envs, n, spread):
    """``envs`` sets of ``[n, T]`` predictions: constant-speed tracks from random poses in a ``spread``-metre box."""
    t = regulation.PREDICTION_TIMES
    x0, y0 = rng.uniform(0, spread, (2, envs, n, 1))
    h = rng.uniform(-np.pi, np.pi, (envs, n, 1))
    v = rng.uniform(0, 4, (envs, n, 1))
    px, py = x0 + v * np.cos(h) * t, y0 + v * np.sin(h) * t
    alive = rng.random((envs, n)) < 0.8
    return px, py, np.broadcast_to(h, px.shape).copy(), alive


@pytest.mark.parametrize("spread", [6.0, 25.0])  # most pairs near; few pairs near (the sparse path's usual case)
def test_conflicts_match_highway_env(spread, x64):
    rng = np.random.default_rng(7)
    px, py, ph, alive = predictions(rng, 16, 10, spread)
    truth = np.stack([brute_force(*a) for a in zip(px, py, ph, alive)])
    assert 0 < truth.sum() < truth.size - len(truth) * 10  # both answers occur
    batched = np.asarray(jax.jit(jax.vmap(regulation.conflicts))(*map(jnp.asarray, (px, py, ph, alive))))
    np.testing.assert_array_equal(batched, truth)
    for e in range(3):
        single = np.asarray(jax.jit(regulation.conflicts)(*map(jnp.asarray, (px[e], py[e], ph[e], alive[e]))))
        np.testing.assert_array_equal(single, truth[e])
    # without a mask every slot counts
    everyone = np.ones(10, bool)
    np.testing.assert_array_equal(np.asarray(regulation.conflicts(px[0], py[0], ph[0])),
                                  brute_force(px[0], py[0], ph[0], everyone))
