"""examples/rollout_all_cores.py: the roll-out split over two CPU devices gives every environment the same
trajectory as on one device (each environment draws from its own key)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
_RUN = """
import json, sys
sys.path.insert(0, "examples")
import rollout_all_cores
out = rollout_all_cores.main(sys.argv[1:])
print(json.dumps({k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in out.items()}))
"""


def _run(*argv):
    env = dict(os.environ, XLA_FLAGS="")  # the suite's conftest pins one device; the example picks its own
    proc = subprocess.run([sys.executable, "-c", _RUN, *argv], cwd=ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_two_devices_give_each_environment_its_one_device_trajectory():
    args = ("--task", "merge-v0", "--num-envs", "6", "--steps", "30", "--seed", "1")
    two, one = _run(*args, "--devices", "2"), _run(*args, "--devices", "1")
    assert (two["devices"], one["devices"]) == (2, 1)
    assert sum(one["episodes"]) > 0  # episodes ended, so resets are part of what is compared
    np.testing.assert_array_equal(two["episodes"], one["episodes"])
    np.testing.assert_array_equal(two["crashes"], one["crashes"])
    np.testing.assert_allclose(two["returns"], one["returns"], rtol=1e-6)
    np.testing.assert_allclose(two["costs"], one["costs"], rtol=1e-6)


def test_bad_arguments_are_refused():
    sys.path.insert(0, os.path.join(ROOT, "examples"))
    try:
        import rollout_all_cores
    finally:
        sys.path.remove(os.path.join(ROOT, "examples"))
    with pytest.raises(ValueError, match="--num-envs must be at least 1"):
        rollout_all_cores.parse_args(["--num-envs", "0"])
