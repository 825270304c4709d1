"""Every resolved run configuration and every command line's ``--help``, as one JSON-able dict.

The pinned copy (``tests/data/config_snapshot.json``) holds the output of the code before the configuration
defaults moved into the algorithms' config dataclasses; ``tests/test_config_snapshot.py`` compares against it.
``python -m tests.config_snapshot OUT.json`` writes the current snapshot.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import sys

# argparse wraps help text at the terminal width; a fixed width makes the text comparable
WIDTH = "120"


def _help(main_or_parser, argv=("--help",)) -> str:
    """What ``main_or_parser(argv)`` prints before exiting on ``--help``."""
    buf = io.StringIO()
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = WIDTH
    try:
        with contextlib.redirect_stdout(buf), contextlib.suppress(SystemExit):
            main_or_parser(list(argv))
    finally:
        if old is None:
            os.environ.pop("COLUMNS")
        else:
            os.environ["COLUMNS"] = old
    return buf.getvalue()


def resolved_configs() -> dict:
    """scenario/algo[/preset] -> the configuration ``python -m train`` would run; failures as their message."""
    from train.__main__ import build_config, parse_args
    from train.config import ALGOS, SCENARIOS

    cases = []
    for scenario in SCENARIOS:
        for algo, sp in ALGOS.items():
            if sp.action not in (SCENARIOS[scenario], "both"):
                continue
            cases.append([f"--scenario={scenario}", f"--algo={algo}"])
            for preset in sp.presets:
                cases.append([f"--scenario={scenario}", f"--algo={algo}", f"--preset={preset}"])
    cases += [["--scenario=highway", "--agents=3"], ["--scenario=highway", "--agents=4", "--hierarchy=0,1|2,3"],
              ["--scenario=highway", "--agents=3", "--hierarchy=0|1|2", "--preset=authors"],
              ["--scenario=highway", "--agents=2", "--algo=sq"],
              ["--scenario=highway", "--agents=3", "--algo=mappo-l"],
              ["--scenario=highway", "--agents=4", "--algo=macpo", "--hierarchy=0,1,2,3"],
              ["--scenario=highway", "--agents=3", "--algo=mappo-l", "--hierarchy=0|1|2"],
              ["--scenario=merge-cavs", "--agents=4", "--algo=mappo-l"],
              ["--scenario=racetrack-v0", "--algo=cs-maddpg", "--agents=4", "--hierarchy=0,1|2,3"],
              ["--scenario=racetrack-v0", "--algo=s-maddpg", "--agents=2", "--hierarchy=1|0"],
              ["--scenario=racetrack-v0", "--algo=c-maddpg", "--hierarchy=0|1|2"],
              ["--scenario=roundabout", "--agents=3", "--hierarchy=0|1|2"],
              ["--scenario=racetrack", "--agents=4", "--algo=cs-maddpg", "--hierarchy=0,1|2,3"],
              ["--scenario=racetrack", "--agents=3", "--algo=macpo"],
              ["--scenario=intersection", "--agents=4", "--algo=s-maddpg", "--hierarchy=0|1|2|3"]]
    out = {}
    for argv in cases:
        try:
            out[" ".join(argv)] = build_config(parse_args(argv))
        except ValueError as e:
            out[" ".join(argv)] = f"ValueError: {e}"
    return out


def help_texts() -> dict:
    """Each command line's ``--help``."""
    import train.__main__ as cli
    from train import experiments, figures, render, report

    return {"train": _help(cli.parse_args), "train.experiments": _help(experiments.main),
            "train.figures": _help(figures.main), "train.render": _help(render.main),
            "train.report": _help(report.main)}


def snapshot() -> dict:
    from train.config import ALGOS, DEFAULTS, HELP, defaults_for, help_for

    return {"python": f"{sys.version_info[0]}.{sys.version_info[1]}", "configs": resolved_configs(),
            "help": help_texts(),
            "defaults": {a: defaults_for(a) for a in ALGOS}, "key_help": {a: help_for(a) for a in ALGOS},
            "DEFAULTS": DEFAULTS, "HELP": HELP}


if __name__ == "__main__":
    with open(sys.argv[1], "w") as f:
        json.dump(snapshot(), f, indent=1)
