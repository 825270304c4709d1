"""CSQ and SQ: constrained Stackelberg Q-learning (paper Algorithm 1) for the discrete scenarios.

``sq`` is the same algorithm with an inactive threshold (d = 100), the paper's discrete "Bi-AC" baseline; its
defaults come from ``train/configs/<scenario>_sq.json``.
"""

from __future__ import annotations

import math

from jaxsmarl.algos.csq_config import CSQConfig
from jaxsmarl.hierarchy import format_hierarchy, is_chain, validate_hierarchy
from jaxsmarl.options import option_table
from train.config import AlgoSpec, register

# Every key, default, help line and rule: the options of CSQConfig.
DEFAULTS, HELP, RULES = option_table(CSQConfig)

# Every coded option of the authors' CSQ at once (`--preset authors`, docs/algorithms.md).
AUTHORS_PRESET = {
    "leader_rule": "authors",
    "infeasible": "argmax",
    "td_action_state": "current",
    "td_action_noise": True,
    "bootstrap_on_truncation": False,
    "terminal_mask": "batch_mean",
}

MAX_AGENTS = 4  # the critics cover the joint-action grid 5^K: 625 joint actions at K = 4


def check(cfg: dict) -> None:
    if cfg["warmup"] > cfg["buffer_size"]:
        raise ValueError(f"'warmup' ({cfg['warmup']}) exceeds buffer_size ({cfg['buffer_size']}): training would "
                         "never start; lower warmup or raise buffer_size")
    k = cfg["agents"]
    if k > MAX_AGENTS:
        raise ValueError(f"'{cfg['algo']}' takes at most {MAX_AGENTS} agents (its critics cover all 5^K joint "
                         f"actions), got agents={k}")
    if cfg["hierarchy"] is not None:
        levels = validate_hierarchy(cfg["hierarchy"], k)
        if cfg["leader_rule"] == "authors" and not is_chain(levels):
            raise ValueError(f"leader_rule 'authors' needs a chain of single agents (e.g. '0|1|2'); hierarchy "
                             f"'{format_hierarchy(levels)}' has a level of several agents")
        cfg["hierarchy"] = format_hierarchy(levels)


def make_agent(config: dict, env):
    from jaxsmarl.algos.csq import CSQAgent

    if not env.discrete:
        raise ValueError(f"scenario '{config['scenario']}' has continuous actions but '{config['algo']}' needs "
                         "discrete actions; use merge, roundabout or highway")
    options = {k: tuple(config[k]) if isinstance(config[k], list) else config[k] for k in DEFAULTS}
    return CSQAgent(CSQConfig(num_actions=(int(env.num_actions),) * env.num_agents,
                              obs_dim=math.prod(env.obs_shape[1:]),
                              absent_agents=bool(getattr(env, "has_absent_agents", False)), **options))


register(
    AlgoSpec("csq", "discrete", "constrained Stackelberg Q-learning (paper Algorithm 1)", DEFAULTS, HELP, RULES,
             make_agent, "offpolicy", check, presets={"authors": AUTHORS_PRESET}),
    AlgoSpec("sq", "discrete", "Stackelberg Q-learning: CSQ with threshold d=100 (the paper's discrete 'Bi-AC')",
             DEFAULTS, HELP, RULES, make_agent, "offpolicy", check, presets={"authors": AUTHORS_PRESET}),
)
