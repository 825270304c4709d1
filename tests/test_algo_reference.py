"""Short training runs of MAPPO-L, MACPO and the MADDPG family, in both network layouts, equal to the outputs
pinned in ``tests/data/algo_reference.npz`` (written by ``python3 -m tests.algo_reference``).

The runs are in 64-bit floats and compared to a relative tolerance of ``RTOL`` of each array's scale: what XLA:CPU
computes differs in the last bits between processors, and training amplifies that (docs/design.md, pinned runs).
Integer and boolean records (which episodes ended, the update order) must be equal, and a crash, arrival or
episode end that comes otherwise changes its float record by a whole unit, far past the tolerance."""

import json

import numpy as np
import pytest

from tests.algo_reference import CONFIGS, FAST, LAYOUTS, REFERENCE, short_run

RUNS = [pytest.param(name, lay, id=f"{name}-{lay}",
                     marks=() if (name, lay) in FAST else pytest.mark.slow)
        for name in CONFIGS for lay in LAYOUTS]
# processors measured to disagree by up to 4e-7 of an array's scale on these runs; a change to an algorithm moves
# its outputs by orders of magnitude more
RTOL = 1e-5


def assert_matches(actual: np.ndarray, pinned: np.ndarray, name: str):
    """``actual`` equals ``pinned`` exactly (integers, booleans) or within ``RTOL`` of ``max(1, max|pinned|)``."""
    assert actual.shape == pinned.shape and actual.dtype == pinned.dtype, (name, actual.shape, pinned.shape)
    if pinned.dtype.kind != "f":
        np.testing.assert_array_equal(actual, pinned, err_msg=name)
        return
    scale = max(1.0, float(np.max(np.abs(pinned)))) if pinned.size else 1.0
    np.testing.assert_allclose(actual, pinned, rtol=0.0, atol=RTOL * scale, err_msg=name)


@pytest.mark.parametrize("name, layout_name", RUNS)
def test_training_matches_the_pinned_run(name, layout_name):
    ref = np.load(REFERENCE)
    # the pinned configuration is the one in CONFIGS: a changed run must be written anew, not compared
    assert json.loads(str(ref[f"config/{name}"])) == json.loads(json.dumps(CONFIGS[name]))
    out = short_run(name, layout_name)
    prefix = f"{name}/{layout_name}/"
    keys = [k for k in ref.files if k.startswith(prefix)]
    assert sorted(k[len(prefix):] for k in keys) == sorted(out)
    assert np.sum(ref[prefix + "episode_returned"]) > 0  # episodes ended: their records are compared
    for k in keys:
        assert_matches(out[k[len(prefix):]], ref[k], k)


def test_the_comparison_catches_a_changed_update():
    """The tolerance is far below what an algorithm change moves: a MAPPO-L run with another actor learning
    rate (10% higher) fails against the pinned run."""
    from unittest import mock

    import tests.algo_reference as ar

    name = FAST[0][0]
    scenario, algo, cfg = CONFIGS[name]
    changed = dict(CONFIGS, **{name: (scenario, algo, dict(cfg, actor_lr=cfg["actor_lr"] * 1.1))})
    with mock.patch.object(ar, "CONFIGS", changed):
        out = ar.short_run(name, FAST[0][1])
    ref = np.load(REFERENCE)
    prefix = f"{name}/{FAST[0][1]}/"
    with pytest.raises(AssertionError):
        for k in (k for k in ref.files if k.startswith(prefix)):
            assert_matches(out[k[len(prefix):]], ref[k], k)
