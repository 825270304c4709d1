"""The framework examples in examples/ run (small settings)."""

from __future__ import annotations

import os
import sys

import pytest

pytest.importorskip("pettingzoo")
EXAMPLES = os.path.join(os.path.dirname(__file__), os.pardir, "examples")


def _example(name):
    sys.path.insert(0, EXAMPLES)
    try:
        return __import__(name)
    finally:
        sys.path.remove(EXAMPLES)


def test_pettingzoo_example_runs_an_episode(tmp_path):
    out = _example("pettingzoo_episode").main(["--scenario", "merge", "--frame", str(tmp_path / "f.png")])
    assert out["steps"] >= 1 and (tmp_path / "f.png").stat().st_size > 0


def test_gymnasium_example_runs():
    out = _example("gymnasium_single_agent").main(["--scenario", "racetrack", "--num-envs", "2",
                                                   "--vector-steps", "2"])
    assert out["steps"] >= 1
