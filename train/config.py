"""Run configuration: defaults, per scenario x algorithm JSON files, validation (before anything compiles).

A configuration is a flat dict. ``load_config(scenario, algo, overrides)`` starts from :data:`DEFAULTS`, applies
``train/configs/<scenario>_<algo>.json`` (the authors' effective hyper-parameters, original_code.md §8.2), then the
overrides (command line, ``--set``), and validates everything. Every problem raises ``ValueError`` whose message
says how to fix it.
"""

from __future__ import annotations

import difflib
import json
import math
import os
from typing import Any

__all__ = ["DEFAULTS", "HELP", "ALGOS", "SCENARIOS", "CONFIG_DIR", "load_config", "validate", "config_path"]

CONFIG_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "configs")

# Known scenarios and their action type (checked again against the env when it is built).
SCENARIOS = {"merge": "discrete", "roundabout": "discrete", "intersection": "continuous", "racetrack": "continuous"}
ALGOS = {"csq": "discrete", "sq": "discrete"}  # sq = CSQ with an inactive threshold (the paper's discrete "Bi-AC")

DEFAULTS: dict[str, Any] = {
    "scenario": "merge",
    "algo": "csq",
    "total_steps": 20000,
    "num_seeds": 8,
    "seed": 0,
    "num_envs": 1,
    "updates_per_step": 1,
    "lr": 1e-3,
    "gamma": 0.95,
    "tau": 0.01,
    "target_update_every": 10,
    "batch_size": 64,
    "warmup": 512,
    "buffer_size": 500000,
    "cost_threshold": [5.0, 5.0],
    "eps_start": [0.1, 0.1],
    "eps_min": [0.0, 0.0],
    "eps_decay": 5e-6,
    "hidden_sizes": [64, 64, 64],
    "init": "torch",
    "leader_rule": "stackelberg",
    "infeasible": "min_cost",
    "tie_break": None,
    "td_action_state": "next",
    "td_action_noise": False,
    "td_equilibrium_net": "online",
    "bootstrap_on_truncation": True,
    "chunk_steps": 1000,
    "checkpoint_every": 5000,
    "eval_episodes": 10,
    "eval_max_steps": 200,
}

HELP: dict[str, str] = {
    "scenario": "driving scenario: merge | roundabout (discrete actions); intersection | racetrack (continuous)",
    "algo": "csq (constrained Stackelberg Q-learning) | sq (same algorithm, threshold d=100: unconstrained)",
    "total_steps": "environment steps per seed (the authors' time_steps: merge 20000, roundabout 10000)",
    "num_seeds": "independent training runs, vmapped in one program",
    "seed": "base seed; run i uses jax.random.fold_in(key(seed), i)",
    "num_envs": "parallel environments per seed (each loop iteration steps all of them)",
    "updates_per_step": "gradient updates per loop iteration (authors: 1 per environment step)",
    "lr": "Adam learning rate of every reward and cost critic (authors' lr_critic)",
    "gamma": "discount factor",
    "tau": "soft target update rate: theta' <- (1-tau) theta' + tau theta",
    "target_update_every": "gradient updates between soft target updates (authors' update_rate)",
    "batch_size": "transitions per gradient update",
    "warmup": "transitions stored before the first update (authors' sample_size)",
    "buffer_size": "replay capacity per seed (FIFO); never more than total_steps slots are allocated",
    "cost_threshold": "per-agent cost limits [d_leader, d_follower] (a single number sets both)",
    "eps_start": "initial exploration probability [leader, follower] (a single number sets both)",
    "eps_min": "exploration floor [leader, follower] (a single number sets both)",
    "eps_decay": "exploration decrease per environment step (linear)",
    "hidden_sizes": "hidden layer widths of each critic MLP",
    "init": "weight init: torch (the authors' PyTorch default) | lecun (flax default)",
    "leader_rule": "stackelberg (paper eq. p14, leader anticipates the follower's best response) | authors "
                   "(their coded max-max over the leader's own Q/G)",
    "infeasible": "when no action satisfies the threshold: min_cost (lowest cost, ties to highest Q) | argmax "
                  "(unconstrained argmax, as the authors)",
    "tie_break": "equal Q values: first (lowest index) | last (highest, the authors' >= loops) | null (rule default)",
    "td_action_state": "state at which the target actions are solved: next (paper, s') | current (authors, s)",
    "td_action_noise": "epsilon-greedy target actions (authors: true)",
    "td_equilibrium_net": "critics used to solve for the target actions: online (p14) | target",
    "bootstrap_on_truncation": "true: only an agent's own termination stops bootstrapping (paper); false: the time "
                               "limit does too (authors)",
    "chunk_steps": "environment steps per compiled chunk; the host logs (and may checkpoint) between chunks",
    "checkpoint_every": "environment steps between checkpoints (a multiple of chunk_steps; 0 = only at the end)",
    "eval_episodes": "greedy evaluation episodes per seed after training (0 = skip)",
    "eval_max_steps": "step cap of one evaluation episode",
}

_CHOICES = {
    "init": ("torch", "lecun"),
    "leader_rule": ("stackelberg", "authors"),
    "infeasible": ("min_cost", "argmax"),
    "tie_break": (None, "first", "last"),
    "td_action_state": ("next", "current"),
    "td_equilibrium_net": ("online", "target"),
}
_PER_AGENT = ("cost_threshold", "eps_start", "eps_min")
_BOOL = ("td_action_noise", "bootstrap_on_truncation")
_INT_MIN = {"total_steps": 1, "num_seeds": 1, "seed": 0, "num_envs": 1, "updates_per_step": 1,
            "target_update_every": 1, "batch_size": 1, "warmup": 1, "buffer_size": 1, "chunk_steps": 1,
            "checkpoint_every": 0, "eval_episodes": 0, "eval_max_steps": 1}


def config_path(scenario: str, algo: str) -> str:
    return os.path.join(CONFIG_DIR, f"{scenario}_{algo}.json")


def _unknown_key(key: str, where: str) -> ValueError:
    close = difflib.get_close_matches(key, DEFAULTS, n=1)
    hint = f" Did you mean '{close[0]}'?" if close else ""
    return ValueError(f"unknown config key '{key}' in {where}.{hint} Valid keys: {', '.join(DEFAULTS)}.")


def load_json(path: str) -> dict:
    try:
        with open(path) as f:
            data = json.load(f)
    except json.JSONDecodeError as e:
        raise ValueError(f"config file {path} is not valid JSON ({e}); fix the file") from e
    if not isinstance(data, dict):
        raise ValueError(f"config file {path} must hold a JSON object of key: value pairs")
    data.pop("_comment", None)
    return data


def load_config(scenario: str | None = None, algo: str | None = None, overrides: dict | None = None,
                config_file: str | None = None) -> dict:
    """Defaults <- ``configs/<scenario>_<algo>.json`` (or ``config_file``) <- ``overrides``; validated."""
    overrides = dict(overrides or {})
    for k in overrides:
        if k not in DEFAULTS:
            raise _unknown_key(k, "the overrides")
    scenario = scenario or overrides.get("scenario") or DEFAULTS["scenario"]
    algo = algo or overrides.get("algo") or DEFAULTS["algo"]
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario '{scenario}'; choose one of {', '.join(SCENARIOS)}")
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm '{algo}'; choose one of {', '.join(ALGOS)}")
    _check_action_type(scenario, algo)
    cfg = dict(DEFAULTS)
    path = config_file or config_path(scenario, algo)
    if config_file or os.path.exists(path):
        data = load_json(path)
        for k in data:
            if k not in DEFAULTS:
                raise _unknown_key(k, path)
        cfg.update(data)
    cfg.update(overrides)
    cfg["scenario"], cfg["algo"] = scenario, algo
    return validate(cfg)


def _check_action_type(scenario: str, algo: str, env_discrete: bool | None = None) -> None:
    discrete = SCENARIOS.get(scenario) == "discrete" if env_discrete is None else env_discrete
    if ALGOS[algo] == "discrete" and not discrete:
        raise ValueError(
            f"scenario '{scenario}' has continuous actions but algorithm '{algo}' needs discrete actions; use "
            f"--scenario merge or --scenario roundabout with {algo}, or a continuous-action algorithm "
            f"(CS-MADDPG) for {scenario}")


def _per_agent(key: str, v: Any) -> list[float]:
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        v = [v, v]
    if not isinstance(v, (list, tuple)) or len(v) != 2 or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in v):
        raise ValueError(f"'{key}' must be a number or a list of two numbers [leader, follower], got {v!r}")
    return [float(x) for x in v]


def validate(cfg: dict) -> dict:
    """Check keys, types and ranges; normalise per-agent values. Returns a new dict."""
    cfg = dict(cfg)
    for k in cfg:
        if k not in DEFAULTS:
            raise _unknown_key(k, "the configuration")
    for k in DEFAULTS:
        cfg.setdefault(k, DEFAULTS[k])
    if cfg["scenario"] not in SCENARIOS:
        raise ValueError(f"unknown scenario '{cfg['scenario']}'; choose one of {', '.join(SCENARIOS)}")
    if cfg["algo"] not in ALGOS:
        raise ValueError(f"unknown algorithm '{cfg['algo']}'; choose one of {', '.join(ALGOS)}")
    _check_action_type(cfg["scenario"], cfg["algo"])
    for k, lo in _INT_MIN.items():
        v = cfg[k]
        if isinstance(v, float) and v.is_integer():
            v = int(v)
        if not isinstance(v, int) or isinstance(v, bool) or v < lo:
            raise ValueError(f"'{k}' must be an integer >= {lo}, got {cfg[k]!r}")
        cfg[k] = v
    for k in _PER_AGENT:
        cfg[k] = _per_agent(k, cfg[k])
    for k in _BOOL:
        if not isinstance(cfg[k], bool):
            raise ValueError(f"'{k}' must be true or false, got {cfg[k]!r}")
    for k, allowed in _CHOICES.items():
        if cfg[k] not in allowed:
            raise ValueError(f"'{k}' must be one of {', '.join(map(str, allowed))}, got {cfg[k]!r}")

    def num(k, lo, hi, lo_open=False, hi_open=False):
        v = cfg[k]
        if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
            raise ValueError(f"'{k}' must be a finite number, got {v!r}")
        if (v <= lo if lo_open else v < lo) or (v >= hi if hi_open else v > hi):
            raise ValueError(f"'{k}' must lie in {'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}, got {v}")
        cfg[k] = float(v)

    num("lr", 0.0, math.inf, lo_open=True, hi_open=True)
    num("gamma", 0.0, 1.0)
    num("tau", 0.0, 1.0, lo_open=True)
    num("eps_decay", 0.0, 1.0)
    for k in ("eps_start", "eps_min"):
        if not all(0.0 <= x <= 1.0 for x in cfg[k]):
            raise ValueError(f"'{k}' values are probabilities and must lie in [0, 1], got {cfg[k]}")
    if any(not math.isfinite(x) for x in cfg["cost_threshold"]):
        raise ValueError(f"'cost_threshold' must be finite (use 100 for 'unconstrained'), got {cfg['cost_threshold']}")
    hs = cfg["hidden_sizes"]
    if not isinstance(hs, (list, tuple)) or len(hs) == 0 or not all(
            isinstance(h, int) and not isinstance(h, bool) and h > 0 for h in hs):
        raise ValueError(f"'hidden_sizes' must be a non-empty list of positive integers, got {hs!r}")
    cfg["hidden_sizes"] = list(hs)

    n = cfg["num_envs"]
    for k in ("total_steps", "chunk_steps"):
        if cfg[k] % n:
            raise ValueError(f"'{k}' ({cfg[k]}) must be a multiple of num_envs ({n}); e.g. set {k} to "
                             f"{(cfg[k] // n + 1) * n}")
    if cfg["checkpoint_every"] % cfg["chunk_steps"]:
        raise ValueError(f"'checkpoint_every' ({cfg['checkpoint_every']}) must be a multiple of chunk_steps "
                         f"({cfg['chunk_steps']}): checkpoints are written between chunks")
    if cfg["warmup"] > cfg["buffer_size"]:
        raise ValueError(f"'warmup' ({cfg['warmup']}) exceeds buffer_size ({cfg['buffer_size']}): training would "
                         "never start; lower warmup or raise buffer_size")
    return cfg
