"""A sweep's run folder record, ``sweep.json``: written when the sweep starts (so an interrupted sweep can be
resumed), completed when it finishes; and the check that ``--resume`` continues the very sweep it holds.

``sweep.json``: ``base`` (the configuration every combination starts from), ``sweep`` (the swept keys and their
values, in order), ``finished``, and per configuration its folder and swept values (plus, once finished, the
last-10% summary); ``timing`` once finished.
"""

from __future__ import annotations

import json
import os

from train.config import RESUME_FREE, defaults_for

__all__ = ["SWEEP_FILE", "is_sweep_folder", "read_sweep", "saved_base", "check_same_sweep"]

SWEEP_FILE = "sweep.json"


def is_sweep_folder(out: str) -> bool:
    return os.path.isfile(os.path.join(out, SWEEP_FILE))


def read_sweep(out: str) -> dict:
    """The ``sweep.json`` of sweep folder ``out`` (ValueError when there is none or it is unreadable)."""
    path = os.path.join(out, SWEEP_FILE)
    if not os.path.isfile(path):
        raise ValueError(f"{out} holds no sweep (no {SWEEP_FILE}); --resume with --sweep continues a sweep's run "
                         f"folder, a plain --resume a single run's")
    try:
        with open(path) as f:
            saved = json.load(f)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path} cannot be read ({e}); the sweep cannot be resumed, start it again with "
                         "--overwrite") from None
    if not isinstance(saved, dict) or not {"base", "sweep", "configurations"} <= set(saved):
        raise ValueError(f"{path} is not a sweep record (needs base, sweep and configurations); start the sweep "
                         "again with --overwrite")
    return saved


def saved_base(out: str) -> dict:
    """The base configuration of sweep folder ``out``, keys added to the library since filled with defaults."""
    base = read_sweep(out)["base"]
    return {**defaults_for(base["algo"]), **base}


def check_same_sweep(saved: dict, configs: list[dict], keys: list[str], values: list[dict], out: str) -> None:
    """``--resume`` continues the sweep saved in ``out`` only: the same swept keys in the same order, the same
    values (so configuration ``c`` is the ``c``-th of the checkpoints' ``[C, S]`` state) and the same other
    settings but for those a resumed run may change (:data:`train.config.RESUME_FREE`)."""
    saved_keys = list(saved["sweep"])
    saved_values = [c["values"] for c in saved["configurations"]]
    if saved_keys != keys or saved_values != values:
        given = " ".join(f"--sweep {k}={json.dumps(v)}" for k, v in saved["sweep"].items())
        raise ValueError(f"--resume: {out} holds another sweep ({len(saved_values)} configurations of "
                         f"{', '.join(saved_keys)}); a sweep resumes only with the same --sweep options in the same "
                         f"order ({given}), or with none; start a different sweep in another --out")
    base = {**defaults_for(saved["base"]["algo"]), **saved["base"]}
    ignore = (*RESUME_FREE, *keys, "env")
    diff = {k: (base.get(k), configs[0][k]) for k in configs[0] if k not in ignore and base.get(k) != configs[0][k]}
    env_now = {k: v for k, v in configs[0]["env"].items() if "env." + k not in keys}
    env_saved = {k: v for k, v in (base.get("env") or {}).items() if "env." + k not in keys}
    if env_now != env_saved:
        diff["env"] = (env_saved, env_now)
    if diff:
        raise ValueError(f"--resume with a different configuration than the saved sweep: {diff}; resume with the "
                         "same options (the saved sweep.json is used when none are given; only --checkpoint-every "
                         "and --eval-episodes may change) or start a new --out")
