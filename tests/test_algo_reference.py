"""Short training runs of MAPPO-L, MACPO and the MADDPG family, in both network layouts, bit for bit equal to the
outputs pinned in ``tests/data/algo_reference.npz`` (written by ``python3 -m tests.algo_reference``)."""

import json

import numpy as np
import pytest

from tests.algo_reference import CONFIGS, FAST, LAYOUTS, REFERENCE, short_run

RUNS = [pytest.param(name, lay, id=f"{name}-{lay}",
                     marks=() if (name, lay) in FAST else pytest.mark.slow)
        for name in CONFIGS for lay in LAYOUTS]


@pytest.mark.parametrize("name, layout_name", RUNS)
def test_training_is_bit_identical_to_the_pinned_run(name, layout_name):
    ref = np.load(REFERENCE)
    # the pinned configuration is the one in CONFIGS: a changed run must be written anew, not compared
    assert json.loads(str(ref[f"config/{name}"])) == json.loads(json.dumps(CONFIGS[name]))
    out = short_run(name, layout_name)
    prefix = f"{name}/{layout_name}/"
    keys = [k for k in ref.files if k.startswith(prefix)]
    assert sorted(k[len(prefix):] for k in keys) == sorted(out)
    assert np.sum(ref[prefix + "episode_returned"]) > 0  # episodes ended: their records are compared
    for k in keys:
        np.testing.assert_array_equal(out[k[len(prefix):]], ref[k], err_msg=k)
