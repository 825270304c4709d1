"""Run configuration: an algorithm registry, defaults, per scenario x algorithm JSON files, validation.

A configuration is a flat dict: the :data:`COMMON` keys every run has (scenario, budget, seeds, chunking,
evaluation) plus the keys of its algorithm. Each algorithm registers an :class:`AlgoSpec` (in a module of
:mod:`train.algos`, discovered automatically) with its defaults, one help line per key and validation rules (read
from the algorithm's config dataclass, :mod:`jaxsmarl.options`), the function that builds its agent and the loop
that trains it (joined by :func:`train.build.make_train`).

``load_config(scenario, algo, overrides)`` starts from the common and the algorithm's defaults, applies
``train/configs/<scenario>_<algo>.json`` (the authors' effective hyper-parameters), then the overrides (command
line, ``--set``), and validates everything. Every problem raises ``ValueError`` whose message says how to fix it.
Nothing here imports JAX, so the command line can answer ``--help`` and reject bad options instantly.
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import os
from typing import Any, Callable

from jaxsmarl.options import TERMINAL_MASKS, Bool, Choice, Int, Num, PerAgent, Sizes

__all__ = ["COMMON", "COMMON_HELP", "AlgoSpec", "ALGOS", "SCENARIOS", "SCENARIO_AGENTS", "CONFIG_DIR", "DEFAULTS",
           "HELP", "register", "spec", "parse_set", "RESUME_FREE", "defaults_for", "help_for", "load_config",
           "read_run_config", "validate", "config_path", "with_overrides", "env_values", "ENV_PREFIX",
           "preset_values", "LEGACY", "MATMUL_PRECISIONS", "TERMINAL_MASKS",
           "Int", "Num", "Choice", "Bool", "PerAgent", "Sizes"]

# an override ``env.<field>`` sets one environment parameter (train.env_params)
ENV_PREFIX = "env."

CONFIG_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "configs")

# Known scenarios and their action type (checked again against the env when it is built).
SCENARIOS = {"merge": "discrete", "roundabout": "discrete", "intersection": "continuous", "racetrack": "continuous",
             "highway": "discrete", "merge-v0": "discrete", "merge-cavs": "discrete", "racetrack-v0": "continuous"}
# Controlled agents per scenario: (default, lowest, highest) for the common key `agents`. `highway` is
# highway-env's highway-v0 with `agents` controlled vehicles (envs_jax.make("highway-v0", controlled_vehicles=K)),
# `merge-v0` highway-env's merge-v0 with its IDM traffic and `agents` controlled vehicles.
# `merge` with 3 or more agents is the authors' merge with K agents (envs_jax.make("merge-k")); 2 keeps the
# two-agent env.
# `merge-cavs` is MARL_CAVs' merge (envs_jax.make("merge-cavs-v0")) at the traffic density whose most CAVs are K:
# K = 3 easy (1-3 CAVs per episode), K = 4 medium (2-4); absent agents are terminated with zero reward and cost.
# `racetrack-v0` is highway-env's racetrack-v0 with `agents` controlled vehicles (continuous steering, per-agent
# reward and cost; envs_jax.make("racetrack-v0", controlled_vehicles=K)). The authors' four scenarios with K >= 3
# are their versions on the traffic core (envs_jax.make("merge-k" / "roundabout-k" / "intersection-k" /
# "racetrack-k", controlled_vehicles=K)); K = 2 the two-agent env.
SCENARIO_AGENTS = {"merge": (2, 2, 8), "roundabout": (2, 2, 8), "intersection": (2, 2, 8), "racetrack": (2, 2, 8),
                   "highway": (2, 2, 8), "merge-v0": (2, 2, 8), "merge-cavs": (3, 3, 4), "racetrack-v0": (3, 2, 8)}
# The scenarios built on the traffic core (K controlled vehicles among background traffic).
TRAFFIC_SCENARIOS = ("highway", "merge-v0", "merge-cavs", "racetrack-v0")

COMMON: dict[str, Any] = {
    "scenario": "merge",
    "algo": "csq",
    "agents": None,
    "total_steps": 20000,
    "num_seeds": 8,
    "seed": 0,
    "num_envs": 1,
    "chunk_steps": 1000,
    "checkpoint_every": 5000,
    "eval_episodes": 10,
    "eval_max_steps": 200,
    "matmul_precision": "highest",
    "env": {},
}

# Keys whose change does not alter a run's training trajectory: a resumed run, and a study keeping a finished run,
# accept new values for them (train.run also accepts a new total_steps, checked against the saved run).
RESUME_FREE = ("checkpoint_every", "eval_episodes", "eval_max_steps")

# The value a key had before it existed, for run folders saved without it (read_run_config): the behaviour those
# runs were trained with. Keys not listed here kept their behaviour under today's default.
LEGACY: dict[str, Any] = {"matmul_precision": "default", "agents": 2}

MATMUL_PRECISIONS = ("highest", "high", "default")

COMMON_HELP: dict[str, str] = {
    "scenario": "driving scenario: merge | roundabout | highway | merge-v0 | merge-cavs (discrete actions); "
                "intersection | "
                "racetrack | racetrack-v0 (continuous)",
    "agents": "controlled agents K (null: the scenario's default; merge, roundabout, intersection, racetrack: 2, "
              "up to 8 (K >= 3: the authors' scenario with K agents, <scenario>-k); highway, merge-v0: 2, up to 8; "
              "merge-cavs: 3 (easy traffic) or 4 (medium); racetrack-v0: 3, 2 to 8)",
    "algo": "training algorithm (see --help for the list)",
    "total_steps": "environment steps per seed, over all its parallel envs (defaults: the authors' budgets)",
    "num_seeds": "independent training runs, vmapped in one program",
    "seed": "base seed; run i uses jax.random.fold_in(key(seed), i)",
    "num_envs": "parallel environments per seed (each loop iteration steps all of them)",
    "chunk_steps": "environment steps per compiled chunk; the host logs (and may checkpoint) between chunks",
    "checkpoint_every": "environment steps between checkpoints (a multiple of chunk_steps; 0 = only at the end)",
    "eval_episodes": "greedy evaluation episodes per seed after training (0 = skip)",
    "eval_max_steps": "step cap of one evaluation episode",
    "matmul_precision": "float32 matrix products in the training programs: highest (full float32 on every "
                        "backend) | high | default (the backend's own: TF32 or bf16 passes on GPUs and TPUs)",
    "env": "environment parameters replacing the scenario's defaults (fields of its params: reward weights, "
           "costs, speed ranges; real-valued, default shapes); one at a time: --set env.collision_reward=-2",
}


# Validation rules (jaxsmarl.options): each returns the normalised value or raises ValueError naming the key and
# what is allowed.

def env_values(key: str, v: Any) -> dict:
    """The ``env`` key: a JSON object of parameter name -> a finite number or a (nested) list of them, numbers as
    floats. Which names the scenario has, and their shapes, are checked when its env is built
    (:mod:`train.env_params`)."""
    def real(x):
        if isinstance(x, (list, tuple)) and x:
            return [real(y) for y in x]
        if isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x):
            return float(x)
        raise ValueError(f"'{key}' values must be finite numbers or lists of them, got {x!r}")

    if not isinstance(v, dict) or not all(isinstance(k, str) and k for k in v):
        raise ValueError(f"'{key}' must be a JSON object of environment parameter name: value, e.g. "
                         f"{{\"collision_reward\": -2}}, got {v!r}")
    return {k: real(x) for k, x in v.items()}


COMMON_RULES: dict[str, Callable] = {
    "total_steps": Int(1), "num_seeds": Int(1), "seed": Int(0), "num_envs": Int(1), "chunk_steps": Int(1),
    "checkpoint_every": Int(0), "eval_episodes": Int(0), "eval_max_steps": Int(1),
    "matmul_precision": Choice(MATMUL_PRECISIONS),
    "env": env_values,
}


def with_overrides(cfg: dict, overrides: dict) -> dict:
    """``cfg`` updated by ``overrides``; an override ``env.<field>`` sets that field inside ``cfg["env"]`` (after
    the overrides' own ``env`` object, if given)."""
    out = {**cfg, **{k: v for k, v in overrides.items() if not k.startswith(ENV_PREFIX)}}
    fields = {k[len(ENV_PREFIX):]: v for k, v in overrides.items() if k.startswith(ENV_PREFIX)}
    if fields:
        base = out.get("env") or {}
        out["env"] = {**(base if isinstance(base, dict) else {}), **fields}
    return out


# ----------------------------------------------------------------------------------------------------------
# The registry.

LOOPS = ("offpolicy", "onpolicy")  # the training loops an algorithm can run in (train.build)
ACTION_KINDS = ("discrete", "continuous", "both")  # the action spaces an algorithm takes


@dataclasses.dataclass(frozen=True)
class AlgoSpec:
    """One trainable algorithm.

    ``defaults``/``help``: its own keys (besides :data:`COMMON`); ``rules``: key -> rule (keys without a rule are
    taken as they are); ``check(cfg)``: cross-key checks on the normalised config, raising ValueError;
    ``make_agent(config, env) -> agent``: the learner for the run (imports JAX lazily); ``loop``: the training loop
    that drives it, ``"offpolicy"`` (:mod:`train.offpolicy`) or ``"onpolicy"`` (:mod:`train.onpolicy`), joined by
    :func:`train.build.make_train`; ``seeds_in_sequence_on_cpu``: on the CPU each device runs its seeds one after
    another, cheaper there for these learners' updates (docs/performance.md);
    ``presets``: name -> values that ``--preset NAME`` sets (after the JSON file, before ``--set``);
    ``flat_only``: a no-hierarchy baseline, which accepts the key ``hierarchy`` only as the flat one (all agents
    on one level) and then drops it.
    """

    name: str
    action: str  # "discrete" | "continuous" | "both"
    summary: str
    defaults: dict
    help: dict
    rules: dict
    make_agent: Callable
    loop: str
    check: Callable | None = None
    presets: dict = dataclasses.field(default_factory=dict)
    seeds_in_sequence_on_cpu: bool = False
    flat_only: bool = False

    def __post_init__(self):
        if self.action not in ACTION_KINDS:
            raise ValueError(f"AlgoSpec {self.name}: action must be discrete, continuous or both")
        if self.loop not in LOOPS:
            raise ValueError(f"AlgoSpec {self.name}: loop must be one of {', '.join(LOOPS)}, got {self.loop!r}")
        missing = [k for k in self.defaults if k not in self.help]
        if missing:
            raise ValueError(f"AlgoSpec {self.name}: keys without a help line: {missing}")
        clash = [k for k in self.defaults if k in COMMON]
        if clash:
            raise ValueError(f"AlgoSpec {self.name}: keys {clash} are common keys")
        for name, values in self.presets.items():
            unknown = [k for k in values if k not in self.defaults]
            if unknown:
                raise ValueError(f"AlgoSpec {self.name}: preset {name!r} sets unknown keys {unknown}")


ALGOS: dict[str, AlgoSpec] = {}


def register(*specs: AlgoSpec) -> None:
    for s in specs:
        ALGOS[s.name] = s


def _discover() -> None:
    """Import every module of :mod:`train.algos`; each registers its algorithms."""
    import importlib
    import pkgutil

    import train.algos as pkg

    for m in sorted(pkgutil.iter_modules(pkg.__path__), key=lambda m: m.name):
        if not m.name.startswith("_"):
            importlib.import_module(f"train.algos.{m.name}")


_discover()


def spec(algo: str) -> AlgoSpec:
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm '{algo}'; choose one of {', '.join(ALGOS)}")
    return ALGOS[algo]


def defaults_for(algo: str) -> dict:
    """Common defaults + the algorithm's."""
    return {**COMMON, **spec(algo).defaults, "algo": algo}


def help_for(algo: str) -> dict:
    return {**COMMON_HELP, **spec(algo).help}


# Back-compatible views: the default algorithm's keys.
DEFAULTS: dict[str, Any] = defaults_for(COMMON["algo"])
HELP: dict[str, str] = help_for(COMMON["algo"])


def config_path(scenario: str, algo: str) -> str:
    return os.path.join(CONFIG_DIR, f"{scenario}_{algo}.json")


def _unknown_key(key: str, where: str, algo: str) -> ValueError:
    valid = defaults_for(algo)
    close = difflib.get_close_matches(key, valid, n=1)
    hint = f" Did you mean '{close[0]}'?" if close else ""
    others = [a for a, s in ALGOS.items() if key in s.defaults]
    if others:
        hint += f" ('{key}' is a key of {', '.join(others)})"
    return ValueError(f"unknown config key '{key}' for algorithm '{algo}' in {where}.{hint} "
                      f"Valid keys: {', '.join(valid)}.")


def load_json(path: str) -> dict:
    try:
        with open(path) as f:
            data = json.load(f)
    except FileNotFoundError:
        raise ValueError(f"config file {path} does not exist; give the path of a JSON file of key: value "
                         "pairs") from None
    except IsADirectoryError:
        raise ValueError(f"config file {path} is a folder, not a JSON file") from None
    except OSError as e:
        raise ValueError(f"config file {path} cannot be read ({e.strerror or e})") from None
    except UnicodeDecodeError as e:
        raise ValueError(f"config file {path} is not valid JSON (not UTF-8 text: {e.reason}); fix the file") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"config file {path} is not valid JSON ({e}); fix the file") from e
    if not isinstance(data, dict):
        raise ValueError(f"config file {path} must hold a JSON object of key: value pairs")
    data.pop("_comment", None)
    return data


def read_run_config(run_dir: str) -> dict:
    """The configuration saved in run folder ``run_dir`` (``config.json``), with every key added to the library
    after the run was saved filled with its default. A new key's default keeps the behaviour the run was trained
    with, so old runs resume, evaluate and render as they were."""
    path = os.path.join(run_dir, "config.json")
    if not os.path.isfile(path):
        raise ValueError(f"{run_dir} is not a run folder: it has no config.json (written by python -m train)")
    saved = load_json(path)
    if saved.get("algo") not in ALGOS:
        raise ValueError(f"{path}: 'algo' is {saved.get('algo')!r}; a run's algorithm is one of {', '.join(ALGOS)}")
    return {**defaults_for(saved["algo"]), **LEGACY, **saved}


def parse_set(items: list[str]) -> dict:
    """``--set KEY=VALUE`` items as overrides: each value read as JSON, a plain word as a string."""
    out = {}
    for item in items:
        if "=" not in item:
            raise ValueError(f"--set expects KEY=VALUE, got {item!r}")
        k, v = item.split("=", 1)
        try:
            out[k.strip()] = json.loads(v)
        except json.JSONDecodeError:
            out[k.strip()] = v
    return out


def preset_values(algo: str, preset: str) -> dict:
    """The values ``--preset preset`` sets for ``algo``; ValueError naming the presets it has."""
    presets = spec(algo).presets
    if preset not in presets:
        have = ", ".join(presets) or "none"
        with_it = [a for a, sp in ALGOS.items() if preset in sp.presets]
        hint = f" ('{preset}' is a preset of {', '.join(with_it)})" if with_it else ""
        raise ValueError(f"algorithm '{algo}' has no preset '{preset}'; its presets: {have}{hint}")
    return dict(presets[preset])


def load_config(scenario: str | None = None, algo: str | None = None, overrides: dict | None = None,
                config_file: str | None = None, preset: str | None = None) -> dict:
    """Defaults <- ``configs/<scenario>_<algo>.json`` (or ``config_file``) <- ``preset`` <- ``overrides``;
    validated."""
    overrides = dict(overrides or {})
    scenario = scenario or overrides.get("scenario") or COMMON["scenario"]
    algo = algo or overrides.get("algo") or COMMON["algo"]
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario '{scenario}'; choose one of {', '.join(SCENARIOS)}")
    spec(algo)
    _check_action_type(scenario, algo)
    valid = defaults_for(algo)
    _drop_flat_hierarchy(scenario, algo, overrides)
    for k in overrides:
        if k not in valid and not (k.startswith(ENV_PREFIX) and len(k) > len(ENV_PREFIX)):
            raise _unknown_key(k, "the overrides", algo)
    cfg = dict(valid)
    path = config_file or config_path(scenario, algo)
    if config_file or os.path.exists(path):
        data = load_json(path)
        for k in data:
            if k not in valid:
                raise _unknown_key(k, path, algo)
        cfg.update(data)
    if preset is not None:
        cfg.update(preset_values(algo, preset))
    cfg = with_overrides(cfg, overrides)
    cfg["scenario"], cfg["algo"] = scenario, algo
    return validate(cfg)


def _drop_flat_hierarchy(scenario: str, algo: str, overrides: dict) -> None:
    """A no-hierarchy baseline (``AlgoSpec.flat_only``) given ``hierarchy``: drop it when it is the flat one (one
    level of every agent), else refuse it."""
    if not spec(algo).flat_only or "hierarchy" not in overrides:
        return
    given = overrides.pop("hierarchy")
    if given is None:
        return
    from jaxsmarl.hierarchy import flat, format_hierarchy, validate_hierarchy

    k = _agents(scenario, overrides.get("agents"))
    levels = validate_hierarchy(given, k)
    if len(levels) != 1:
        raise ValueError(f"'{algo}' is a no-hierarchy baseline (all {k} agents act at once) but hierarchy "
                         f"'{format_hierarchy(levels)}' has {len(levels)} levels; leave --hierarchy out or give the "
                         f"flat '{format_hierarchy(flat(k))}' (csq and sq train hierarchies)")


def _check_action_type(scenario: str, algo: str) -> None:
    s = spec(algo)
    if s.action not in (SCENARIOS[scenario], "both"):
        fits = [a for a, sp in ALGOS.items() if sp.action in (SCENARIOS[scenario], "both")]
        scen = [n for n, t in SCENARIOS.items() if t == s.action]
        raise ValueError(
            f"scenario '{scenario}' has {SCENARIOS[scenario]} actions but algorithm '{algo}' needs {s.action} "
            f"actions; use {algo} with {' or '.join('--scenario ' + x for x in scen)}, or train {scenario} with "
            f"{', '.join(fits) or 'an algorithm for ' + SCENARIOS[scenario] + ' actions (none registered)'}")


def _agents(scenario: str, value: Any) -> int:
    """The number of controlled agents: ``value`` checked against the scenario's range (None: its default)."""
    default, lo, hi = SCENARIO_AGENTS[scenario]
    if value is None:
        return default
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
        allowed = str(lo) if lo == hi else f"{lo}..{hi}"
        more = [n for n, (_, a, b) in SCENARIO_AGENTS.items() if b > 2]
        hint = f"; K agents: --scenario {' or '.join(more)}" if lo == hi else ""
        raise ValueError(f"'agents' for scenario '{scenario}' must be {allowed}, got {value!r}{hint}")
    return value


def validate(cfg: dict) -> dict:
    """Check keys, types and ranges; normalise per-agent values. Returns a new dict."""
    cfg = dict(cfg)
    algo = cfg.get("algo", COMMON["algo"])
    s = spec(algo)
    if cfg.get("scenario", COMMON["scenario"]) not in SCENARIOS:
        raise ValueError(f"unknown scenario '{cfg['scenario']}'; choose one of {', '.join(SCENARIOS)}")
    valid = defaults_for(algo)
    for k in cfg:
        if k not in valid:
            raise _unknown_key(k, "the configuration", algo)
    for k, v in valid.items():
        cfg.setdefault(k, v)
    _check_action_type(cfg["scenario"], algo)
    cfg["agents"] = n_agents = _agents(cfg["scenario"], cfg["agents"])
    for k, rule in {**COMMON_RULES, **s.rules}.items():
        cfg[k] = rule(k, cfg[k], n_agents) if isinstance(rule, PerAgent) else rule(k, cfg[k])

    n = cfg["num_envs"]
    for k in ("total_steps", "chunk_steps"):
        if cfg[k] % n:
            raise ValueError(f"'{k}' ({cfg[k]}) must be a multiple of num_envs ({n}); e.g. set {k} to "
                             f"{(cfg[k] // n + 1) * n}")
    if cfg["checkpoint_every"] % cfg["chunk_steps"]:
        raise ValueError(f"'checkpoint_every' ({cfg['checkpoint_every']}) must be a multiple of chunk_steps "
                         f"({cfg['chunk_steps']}): checkpoints are written between chunks")
    if s.check is not None:
        s.check(cfg)
    return cfg
