"""The resolved configuration of every scenario x algorithm x preset and every command line's ``--help`` equal
the pinned snapshot (tests/config_snapshot.py). The pin was written by the code before the defaults moved into the
config dataclasses; it is rewritten (``python -m tests.config_snapshot tests/data/config_snapshot.json``) only when
an option or scenario is added on purpose, after checking that nothing else in it changed."""

import json
import os

import pytest

from tests.config_snapshot import snapshot

PINNED = os.path.join(os.path.dirname(__file__), "data", "config_snapshot.json")


@pytest.fixture(scope="module")
def pair():
    with open(PINNED) as f:
        pinned = json.load(f)
    return pinned, json.loads(json.dumps(snapshot()))


@pytest.mark.parametrize("part", ["configs", "defaults", "key_help", "DEFAULTS", "HELP"])
def test_resolved_configs_unchanged(pair, part):
    pinned, now = pair
    assert now[part].keys() == pinned[part].keys()
    for name in pinned[part]:
        assert now[part][name] == pinned[part][name], name


@pytest.mark.parametrize("cli", ["train", "train.experiments", "train.figures", "train.render", "train.report"])
def test_help_unchanged(pair, cli):
    import sys

    pinned, now = pair
    if f"{sys.version_info[0]}.{sys.version_info[1]}" != pinned["python"]:
        pytest.skip(f"--help pinned under Python {pinned['python']}, whose argparse formats it")
    assert now["help"][cli] == pinned["help"][cli]


def test_shipped_configs_hold_values_only():
    """Every key of train/configs/<scenario>_<algo>.json is a configuration key of that algorithm (narratives
    live in docs/configs.md)."""
    import glob

    from train.config import CONFIG_DIR, defaults_for

    files = sorted(glob.glob(os.path.join(CONFIG_DIR, "*.json")))
    assert files
    for path in files:
        algo = os.path.basename(path)[:-5].split("_", 1)[1]
        with open(path) as f:
            keys = set(json.load(f))
        assert keys <= set(defaults_for(algo)), (path, keys - set(defaults_for(algo)))
