"""jaxsmarl.options: config dataclass fields that carry their help line and validation rule."""

import dataclasses
import os
import subprocess
import sys

import pytest

from jaxsmarl.options import Int, Num, option, option_table


@dataclasses.dataclass(frozen=True)
class Example:
    size: int = 3  # not a user option
    steps: int = option(10, "steps per update", Int(1))
    rates: tuple = option((0.1, 0.2), "one rate per agent")
    limit: float = option(1.0, "the constrained variant's limit", Num(0.0), only="constrained")


def test_option_table_reads_defaults_help_and_rules_in_field_order():
    defaults, helps, rules = option_table(Example)
    assert list(defaults) == ["steps", "rates"] and defaults == {"steps": 10, "rates": [0.1, 0.2]}
    assert helps == {"steps": "steps per update", "rates": "one rate per agent"}
    assert list(rules) == ["steps"] and rules["steps"]("steps", 4.0) == 4
    with pytest.raises(ValueError, match="'steps' must be an integer >= 1"):
        rules["steps"]("steps", 0)
    defaults, _, rules = option_table(Example, ("constrained",))
    assert list(defaults) == ["steps", "rates", "limit"] and set(rules) == {"steps", "limit"}
    assert Example().limit == 1.0 and Example(limit=2.0).limit == 2.0  # still an ordinary field


def test_option_misuse_is_refused():
    with pytest.raises(TypeError, match="help"):
        option(1, "")
    with pytest.raises(TypeError, match="config dataclass"):
        option_table(dict)


def test_algorithm_configs_import_without_jax():
    """The command line reads every default from the config dataclasses before JAX starts."""
    code = ("import sys, train.config, jaxsmarl.algos.csq_config, jaxsmarl.algos.maddpg_config, "
            "jaxsmarl.algos.ppo_config; print('jax' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True, timeout=60,
                         cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "False"
