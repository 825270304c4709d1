"""CSQ and SQ: constrained Stackelberg Q-learning (paper Algorithm 1) for the discrete scenarios.

``sq`` is the same algorithm with an inactive threshold (d = 100), the paper's discrete "Bi-AC" baseline; its
defaults come from ``train/configs/<scenario>_sq.json``.
"""

from __future__ import annotations

import math

from train.config import TERMINAL_MASKS, AlgoSpec, Bool, Choice, Int, Num, PerAgent, Sizes, register

DEFAULTS = {
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
    "terminal_mask": "sample",
    "hierarchy": None,
}

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

HELP = {
    "updates_per_step": "gradient updates per loop iteration (authors: 1 per environment step)",
    "lr": "Adam learning rate of every reward and cost critic (authors' lr_critic)",
    "gamma": "discount factor",
    "tau": "soft target update rate: theta' <- (1-tau) theta' + tau theta",
    "target_update_every": "gradient updates between soft target updates (authors' update_rate)",
    "batch_size": "transitions per gradient update",
    "warmup": "transitions stored before the first update (authors' sample_size)",
    "buffer_size": "replay capacity per seed (FIFO); never more than total_steps slots are allocated",
    "cost_threshold": "per-agent cost limits [d_leader, d_follower], one per agent (a single number sets all)",
    "eps_start": "initial exploration probability [leader, follower], one per agent (a single number sets all)",
    "eps_min": "exploration floor [leader, follower], one per agent (a single number sets all)",
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
    "terminal_mask": "which transitions bootstrap: sample (each transition's own terminal flag) | batch_mean (the "
                     "authors' effective rule: every transition bootstraps, discount scaled by the batch's done "
                     "fraction)",
    "hierarchy": "who decides before whom: levels of agent indices, '|' between levels, ',' within one, e.g. "
                 "'0|1|2' (chain), '0,1|2' (two leaders), '0,1,2' (no hierarchy); null: the chain 0|1|...|K-1 "
                 "(docs/algorithms.md)",
}

PROB = PerAgent(Num(0.0, 1.0, hint="values are probabilities and must lie in [0, 1]"))
RULES = {
    "updates_per_step": Int(1), "target_update_every": Int(1), "batch_size": Int(1), "warmup": Int(1),
    "buffer_size": Int(1),
    "lr": Num(0.0, math.inf, lo_open=True, hi_open=True), "gamma": Num(0.0, 1.0), "tau": Num(0.0, 1.0, lo_open=True),
    "eps_decay": Num(0.0, 1.0), "eps_start": PROB, "eps_min": PROB, "cost_threshold": PerAgent(Num(hint="use 100 for 'unconstrained'")),
    "hidden_sizes": Sizes(), "init": Choice(("torch", "lecun")), "leader_rule": Choice(("stackelberg", "authors")),
    "infeasible": Choice(("min_cost", "argmax")), "tie_break": Choice((None, "first", "last")),
    "td_action_state": Choice(("next", "current")), "td_equilibrium_net": Choice(("online", "target")),
    "td_action_noise": Bool(), "bootstrap_on_truncation": Bool(), "terminal_mask": Choice(TERMINAL_MASKS),
}


def check(cfg: dict) -> None:
    if cfg["warmup"] > cfg["buffer_size"]:
        raise ValueError(f"'warmup' ({cfg['warmup']}) exceeds buffer_size ({cfg['buffer_size']}): training would "
                         "never start; lower warmup or raise buffer_size")
    k = cfg["agents"]
    if k > MAX_AGENTS:
        raise ValueError(f"'{cfg['algo']}' takes at most {MAX_AGENTS} agents (its critics cover all 5^K joint "
                         f"actions), got agents={k}")
    if cfg["hierarchy"] is not None:
        from jaxsmarl.hierarchy import format_hierarchy, is_chain, validate_hierarchy

        levels = validate_hierarchy(cfg["hierarchy"], k)
        if cfg["leader_rule"] == "authors" and not is_chain(levels):
            raise ValueError(f"leader_rule 'authors' needs a chain of single agents (e.g. '0|1|2'); hierarchy "
                             f"'{format_hierarchy(levels)}' has a level of several agents")
        cfg["hierarchy"] = format_hierarchy(levels)


def make_agent(config: dict, env):
    from jaxsmarl.algos.csq import CSQAgent, CSQConfig

    if not env.discrete:
        raise ValueError(f"scenario '{config['scenario']}' has continuous actions but '{config['algo']}' needs "
                         "discrete actions; use merge, roundabout or highway")
    n = env.num_agents
    return CSQAgent(CSQConfig(
        num_actions=(int(env.num_actions),) * n, obs_dim=math.prod(env.obs_shape[1:]),
        hidden_sizes=tuple(config["hidden_sizes"]), init=config["init"], lr=config["lr"],
        gamma=config["gamma"], tau=config["tau"], target_update_every=config["target_update_every"],
        batch_size=config["batch_size"], cost_threshold=tuple(config["cost_threshold"]),
        eps_start=tuple(config["eps_start"]), eps_min=tuple(config["eps_min"]), eps_decay=config["eps_decay"],
        leader_rule=config["leader_rule"], infeasible=config["infeasible"], tie_break=config["tie_break"],
        td_action_state=config["td_action_state"], td_action_noise=config["td_action_noise"],
        td_equilibrium_net=config["td_equilibrium_net"],
        bootstrap_on_truncation=config["bootstrap_on_truncation"], terminal_mask=config["terminal_mask"],
        hierarchy=config.get("hierarchy"), absent_agents=bool(getattr(env, "has_absent_agents", False)),
    ))


def make_train(config: dict, env=None):
    from train.loop import make_env, make_offpolicy_train

    env = make_env(config["scenario"], config.get("agents")) if env is None else env
    return make_offpolicy_train(config, env, make_agent(config, env[0]))


register(
    AlgoSpec("csq", "discrete", "constrained Stackelberg Q-learning (paper Algorithm 1)", DEFAULTS, HELP, RULES,
             make_train, check, presets={"authors": AUTHORS_PRESET}),
    AlgoSpec("sq", "discrete", "Stackelberg Q-learning: CSQ with threshold d=100 (the paper's discrete 'Bi-AC')",
             DEFAULTS, HELP, RULES, make_train, check, presets={"authors": AUTHORS_PRESET}),
)
