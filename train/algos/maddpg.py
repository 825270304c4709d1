"""CS-MADDPG (paper Algorithm 2) and its relatives for the continuous scenarios (intersection, racetrack,
racetrack-v0 with K agents).

* ``cs-maddpg``: constrained Stackelberg MADDPG (follower conditioned on the leader's action, leader gradient
  through the follower's actor, cost critics and Lagrange multipliers);
* ``s-maddpg``: the same without cost critics and multipliers (the paper's continuous "Bi-AC" curves);
* ``c-maddpg``: constrained MADDPG without the leader/follower structure (each actor on its own observation);
* ``maddpg``: plain MADDPG.

With K agents (``--agents``) the Stackelberg variants take any ``--hierarchy`` (default the chain 0|1|...|K-1); the
others have one level, the flat counterpart.

Defaults are the authors' effective hyper-parameters (docs/algorithms.md); per-scenario values (threshold,
budget) are in ``train/configs/<scenario>_<algo>.json``.
"""

from __future__ import annotations

import math

from jaxsmarl.algos.maddpg_config import MADDPGConfig
from jaxsmarl.hierarchy import flat, format_hierarchy, validate_hierarchy
from jaxsmarl.options import option_table
from train.config import AlgoSpec, register

# Every coded option of the authors' MADDPG learners at once (`--preset authors`, docs/algorithms.md); the
# constrained variants add their multiplier rule.
AUTHORS_PRESET = {"critic_input": "own", "bootstrap_on_truncation": False, "actor_order": "sequential",
                  "terminal_mask": "batch_mean"}
CONSTRAINED_AUTHORS_PRESET = {**AUTHORS_PRESET, "lambda_rule": "authors"}

# Every key, default, help line and rule: the options of MADDPGConfig; the variants without cost critics lack the
# constrained ones and keep an exploration floor of 0.05 (the authors' Bi-AC runs).
CONSTRAINED_DEFAULTS, HELP, CONSTRAINED_RULES = option_table(MADDPGConfig, ("constrained",))
_defaults, _, RULES = option_table(MADDPGConfig)
UNCONSTRAINED_DEFAULTS = {**_defaults, "noise_min": [0.05, 0.05], "eps_min": [0.05, 0.05]}

VARIANTS = {  # name: (stackelberg, constrained)
    "cs-maddpg": (True, True),
    "s-maddpg": (True, False),
    "c-maddpg": (False, True),
    "maddpg": (False, False),
}


def check(cfg: dict) -> None:
    if cfg["warmup"] > cfg["buffer_size"]:
        raise ValueError(f"'warmup' ({cfg['warmup']}) exceeds buffer_size ({cfg['buffer_size']}): training would "
                         "never start; lower warmup or raise buffer_size")
    if cfg["batch_size"] > cfg["total_steps"]:
        raise ValueError(f"'batch_size' ({cfg['batch_size']}) exceeds total_steps ({cfg['total_steps']}); lower it")
    if "lambda_init" in cfg and cfg["lambda_init"] > cfg["lambda_max"]:
        raise ValueError(f"'lambda_init' ({cfg['lambda_init']}) exceeds lambda_max ({cfg['lambda_max']}); the "
                         "multiplier lives in [0, lambda_max]")
    if cfg["hierarchy"] is not None:
        levels = validate_hierarchy(cfg["hierarchy"], cfg["agents"])
        if not VARIANTS[cfg["algo"]][0] and len(levels) > 1:
            stackelberg = {"c-maddpg": "cs-maddpg", "maddpg": "s-maddpg"}[cfg["algo"]]
            raise ValueError(f"'{cfg['algo']}' has no leaders and followers, so its hierarchy is one level "
                             f"('{format_hierarchy(flat(cfg['agents']))}'), got '{format_hierarchy(levels)}'; use "
                             f"{stackelberg} for a hierarchy")
        cfg["hierarchy"] = format_hierarchy(levels)


def make_agent(config: dict, env):
    from jaxsmarl.algos.maddpg import MADDPGAgent

    if env.discrete:
        raise ValueError(f"scenario '{config['scenario']}' has discrete actions but '{config['algo']}' needs "
                         "continuous actions; use intersection, racetrack or racetrack-v0")
    stackelberg, constrained = VARIANTS[config["algo"]]
    keys = CONSTRAINED_DEFAULTS if constrained else UNCONSTRAINED_DEFAULTS
    options = {k: tuple(config[k]) if isinstance(config[k], list) else config[k] for k in keys}
    return MADDPGAgent(MADDPGConfig(action_dim=int(env.action_shape[-1]), obs_dim=math.prod(env.obs_shape[1:]),
                                    n_agents=int(env.num_agents), stackelberg=stackelberg, constrained=constrained,
                                    **options))


register(
    AlgoSpec("cs-maddpg", "continuous", "constrained Stackelberg MADDPG (paper Algorithm 2)",
             CONSTRAINED_DEFAULTS, HELP, CONSTRAINED_RULES, make_agent, "offpolicy", check,
             presets={"authors": CONSTRAINED_AUTHORS_PRESET}, seeds_in_sequence_on_cpu=True),
    AlgoSpec("s-maddpg", "continuous", "Stackelberg MADDPG without constraints (the paper's continuous 'Bi-AC')",
             UNCONSTRAINED_DEFAULTS, HELP, RULES, make_agent, "offpolicy", check,
             presets={"authors": AUTHORS_PRESET}, seeds_in_sequence_on_cpu=True),
    AlgoSpec("c-maddpg", "continuous", "constrained MADDPG without leader/follower structure",
             CONSTRAINED_DEFAULTS, HELP, CONSTRAINED_RULES, make_agent, "offpolicy", check,
             presets={"authors": CONSTRAINED_AUTHORS_PRESET}, seeds_in_sequence_on_cpu=True),
    AlgoSpec("maddpg", "continuous", "plain MADDPG (each actor on its own observation, no constraints)",
             UNCONSTRAINED_DEFAULTS, HELP, RULES, make_agent, "offpolicy", check,
             presets={"authors": AUTHORS_PRESET}, seeds_in_sequence_on_cpu=True),
)
