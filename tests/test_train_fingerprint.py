"""A short training run of every algorithm ends in the same state and metrics, bit for bit, as the code before the
configuration and loop restructuring (digests pinned in tests/data/train_fingerprint.json by
tests/train_fingerprint.py). Slow: five compilations."""

import json
import os

import pytest

from tests.train_fingerprint import RUNS, digest

PINNED = os.path.join(os.path.dirname(__file__), "data", "train_fingerprint.json")


@pytest.mark.slow
@pytest.mark.parametrize("algo", list(RUNS))
def test_short_run_is_bit_identical(algo):
    import jax

    if jax.default_backend() != "cpu" or jax.config.jax_enable_x64:
        pytest.skip("digests pinned on the CPU backend in float32")
    with open(PINNED) as f:
        assert digest(algo) == json.load(f)[algo]
