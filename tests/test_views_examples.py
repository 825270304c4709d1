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


@pytest.mark.slow  # compiles a traffic task's step alone and vmapped
def test_gymnasium_example_runs_on_a_single_agent_task():
    out = _example("gymnasium_single_agent").main(["--scenario", "highway-fast-v0", "--duration", "3",
                                                   "--num-envs", "2", "--vector-steps", "2"])
    assert 1 <= out["steps"] <= 3  # 3 s at one decision per second (fewer if the car crashed)
