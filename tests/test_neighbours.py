"""``neighbours.front_rear`` against a plain Python transcription of ``Road.neighbour_vehicles``'s loop,
on coordinates drawn from a few integers so that equal ``s`` (the tie rules) occur often."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from envs_jax import neighbours as N


def brute_force(s_ego, s, on):
    """highway-env's loop: ``s <= s_v and s_v <= s_front`` (a later tie wins), ``s_v < s and s_v > s_rear``
    (the first tie stays)."""
    front = rear = -1
    s_front = s_rear = None
    for j, (s_v, ok) in enumerate(zip(s, on)):
        if not ok:
            continue
        if s_ego <= s_v and (s_front is None or s_v <= s_front):
            s_front, front = s_v, j
        if s_v < s_ego and (s_rear is None or s_v > s_rear):
            s_rear, rear = s_v, j
    return front, rear


@pytest.mark.parametrize("use_x64", [False, True])
def test_front_rear_ties(use_x64):
    with jax.enable_x64(use_x64):
        check_ties(use_x64)


def check_ties(x64):
    rng = np.random.default_rng(0)
    n_ego, n_query, n_obj = 7, 4, 13
    dtype = np.float64 if x64 else np.float32
    s = rng.integers(-3, 4, size=(n_ego, n_query, n_obj)).astype(dtype)
    s_ego = rng.integers(-3, 4, size=(n_ego, n_query)).astype(dtype)
    on = rng.random((n_ego, n_query, n_obj)) < 0.6
    s[0, 0, :] = -np.inf  # infinite coordinates follow the same comparisons
    front, rear = jax.jit(N.front_rear)(s_ego, s, on)
    want = np.array([[brute_force(s_ego[e, q], s[e, q], on[e, q]) for q in range(n_query)] for e in range(n_ego)])
    np.testing.assert_array_equal(np.asarray(front), want[..., 0])
    np.testing.assert_array_equal(np.asarray(rear), want[..., 1])
    ties = sum(len(set(s[e, q][on[e, q]])) < on[e, q].sum() for e in range(n_ego) for q in range(n_query))
    assert ties > n_ego * n_query / 2 and (want >= 0).mean() > 0.5  # the tie rules are exercised
