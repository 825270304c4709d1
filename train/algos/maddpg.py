"""CS-MADDPG (paper Algorithm 2) and its relatives for the continuous scenarios (intersection, racetrack).

* ``cs-maddpg``: constrained Stackelberg MADDPG (follower conditioned on the leader's action, leader gradient
  through the follower's actor, cost critics and Lagrange multipliers);
* ``s-maddpg``: the same without cost critics and multipliers (the paper's continuous "Bi-AC" curves);
* ``c-maddpg``: constrained MADDPG without the leader/follower structure (each actor on its own observation);
* ``maddpg``: plain MADDPG.

Defaults are the authors' effective hyper-parameters (docs/algorithms.md); per-scenario values (threshold,
budget) are in ``train/configs/<scenario>_<algo>.json``.
"""

from __future__ import annotations

import math

from train.config import TERMINAL_MASKS, AlgoSpec, Bool, Choice, Int, Num, PerAgent, Sizes, register

_COMMON_DEFAULTS = {
    "updates_per_step": 1,
    "lr_actor": 1e-4,
    "lr_critic": 1e-3,
    "gamma": 0.95,
    "tau": 0.01,
    "target_update_every": 10,
    "batch_size": 256,
    "warmup": 512,
    "buffer_size": 500000,
    "noise_start": [0.1, 0.1],
    "noise_min": [0.05, 0.05],
    "eps_start": [0.1, 0.1],
    "eps_min": [0.05, 0.05],
    "explore_decay": 5e-7,
    "hidden_sizes": [64, 64, 64],
    "init": "torch",
    "critic_input": "joint",
    "bootstrap_on_truncation": True,
    "actor_order": "simultaneous",
    "terminal_mask": "sample",
}

_CONSTRAINED_DEFAULTS = {
    "cost_threshold": [5.0, 5.0],
    "lambda_rule": "dual",
    "lr_lambda": 1e-3,
    "lambda_init": 0.0,
    "lambda_max": 100.0,
}

# Every coded option of the authors' MADDPG learners at once (`--preset authors`, docs/algorithms.md); the
# constrained variants add their multiplier rule.
AUTHORS_PRESET = {"critic_input": "own", "bootstrap_on_truncation": False, "actor_order": "sequential",
                  "terminal_mask": "batch_mean"}
CONSTRAINED_AUTHORS_PRESET = {**AUTHORS_PRESET, "lambda_rule": "authors"}

UNCONSTRAINED_DEFAULTS = dict(_COMMON_DEFAULTS)  # the authors' Bi-AC runs: exploration floor 0.05
CONSTRAINED_DEFAULTS = {**_COMMON_DEFAULTS, "noise_min": [0.0, 0.0], "eps_min": [0.0, 0.0],
                        **_CONSTRAINED_DEFAULTS}  # the authors' CS-MADDPG runs: floor 0

HELP = {
    "updates_per_step": "gradient updates per loop iteration (authors: 1 per environment step)",
    "lr_actor": "Adam learning rate of both actors",
    "lr_critic": "Adam learning rate of every reward and cost critic",
    "gamma": "discount factor",
    "tau": "soft target update rate: theta' <- (1-tau) theta' + tau theta (all actors and critics)",
    "target_update_every": "gradient updates between soft target updates (authors' update_rate)",
    "batch_size": "transitions per gradient update",
    "warmup": "transitions stored before the first update (authors' sample_size)",
    "buffer_size": "replay capacity per seed (FIFO); never more than total_steps slots are allocated",
    "noise_start": "initial Gaussian action-noise std [leader, follower] (a single number sets both)",
    "noise_min": "floor of the action-noise std [leader, follower]",
    "eps_start": "initial probability of a uniform random action [leader, follower]",
    "eps_min": "floor of the random-action probability [leader, follower]",
    "explore_decay": "decrease of noise std and random-action probability per environment step (linear)",
    "hidden_sizes": "hidden layer widths of every actor and critic MLP",
    "init": "weight init: torch (the authors' PyTorch default) | lecun (flax default)",
    "critic_input": "state seen by the centralized critics: joint (paper, s = both observations) | own (authors, "
                    "the agent's own observation)",
    "bootstrap_on_truncation": "true: only an agent's own termination stops bootstrapping (paper); false: the time "
                               "limit does too (authors)",
    "actor_order": "simultaneous: both actors step from the same parameters (Algorithm 2) | sequential: the "
                   "leader steps first and the follower's actor loss and multiplier see the stepped leader actor "
                   "(the authors' leader.train() then follower.train())",
    "terminal_mask": "which transitions bootstrap: sample (each transition's own terminal flag) | batch_mean (the "
                     "authors' effective rule: every transition bootstraps, discount scaled by the batch's done "
                     "fraction), for the reward and the cost critics",
    "cost_threshold": "per-agent cost limits [d_leader, d_follower] on the cost critics (a single number sets both)",
    "lambda_rule": "Lagrange multiplier rule: dual (paper p22: lambda += lr (G - d), projected to [0, lambda_max], "
                   "penalty lambda (G - d)) | authors (lambda += lr relu(G - d), never decreases, hinge penalty)",
    "lr_lambda": "multiplier step size (the paper's slower timescale beta_i)",
    "lambda_init": "initial multiplier of both agents (authors' configs: 0)",
    "lambda_max": "upper bound of the multipliers (authors' configs: 100)",
}

_NOISE = PerAgent(Num(0.0, math.inf, hint="a standard deviation, >= 0"))
_PROB = PerAgent(Num(0.0, 1.0, hint="values are probabilities and must lie in [0, 1]"))
_POS = Num(0.0, math.inf, lo_open=True, hi_open=True)
RULES = {
    "updates_per_step": Int(1), "target_update_every": Int(1), "batch_size": Int(1), "warmup": Int(1),
    "buffer_size": Int(1), "lr_actor": _POS, "lr_critic": _POS, "gamma": Num(0.0, 1.0),
    "tau": Num(0.0, 1.0, lo_open=True), "noise_start": _NOISE, "noise_min": _NOISE, "eps_start": _PROB,
    "eps_min": _PROB, "explore_decay": Num(0.0, 1.0), "hidden_sizes": Sizes(), "init": Choice(("torch", "lecun")),
    "critic_input": Choice(("joint", "own")), "bootstrap_on_truncation": Bool(),
    "actor_order": Choice(("simultaneous", "sequential")), "terminal_mask": Choice(TERMINAL_MASKS),
}
CONSTRAINED_RULES = {
    **RULES, "cost_threshold": PerAgent(Num(hint="the cost critics estimate discounted episode costs")),
    "lambda_rule": Choice(("dual", "authors")), "lr_lambda": Num(0.0, math.inf, hi_open=True),
    "lambda_init": Num(0.0, math.inf, hi_open=True), "lambda_max": Num(0.0, math.inf, hi_open=True),
}

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


def make_agent(config: dict, env):
    from jaxsmarl.algos.maddpg import MADDPGAgent, MADDPGConfig

    if env.discrete:
        raise ValueError(f"scenario '{config['scenario']}' has discrete actions but '{config['algo']}' needs "
                         "continuous actions; use intersection or racetrack")
    stackelberg, constrained = VARIANTS[config["algo"]]
    extra = {}
    if constrained:
        extra = dict(cost_threshold=tuple(config["cost_threshold"]), lambda_rule=config["lambda_rule"],
                     lr_lambda=config["lr_lambda"], lambda_init=config["lambda_init"],
                     lambda_max=config["lambda_max"])
    return MADDPGAgent(MADDPGConfig(
        action_dim=int(env.action_shape[-1]), obs_dim=int(env.obs_shape[-1]),
        hidden_sizes=tuple(config["hidden_sizes"]), init=config["init"], stackelberg=stackelberg,
        constrained=constrained, critic_input=config["critic_input"], lr_actor=config["lr_actor"],
        lr_critic=config["lr_critic"], gamma=config["gamma"], tau=config["tau"],
        target_update_every=config["target_update_every"], noise_start=tuple(config["noise_start"]),
        noise_min=tuple(config["noise_min"]), eps_start=tuple(config["eps_start"]), eps_min=tuple(config["eps_min"]),
        explore_decay=config["explore_decay"], bootstrap_on_truncation=config["bootstrap_on_truncation"],
        actor_order=config["actor_order"], terminal_mask=config["terminal_mask"], **extra,
    ))


def make_train(config: dict, env=None):
    import jax

    from train.loop import make_env, make_offpolicy_train

    env = make_env(config["scenario"]) if env is None else env
    trainer = make_offpolicy_train(config, env, make_agent(config, env[0]))
    # on the CPU each device's seeds run one after another, which is faster there (CSQ gains nothing, so it keeps
    # them batched; docs/performance.md)
    return trainer._replace(seeds_in_sequence=jax.default_backend() == "cpu")


register(
    AlgoSpec("cs-maddpg", "continuous", "constrained Stackelberg MADDPG (paper Algorithm 2)",
             CONSTRAINED_DEFAULTS, HELP, CONSTRAINED_RULES, make_train, check,
             presets={"authors": CONSTRAINED_AUTHORS_PRESET}),
    AlgoSpec("s-maddpg", "continuous", "Stackelberg MADDPG without constraints (the paper's continuous 'Bi-AC')",
             UNCONSTRAINED_DEFAULTS, HELP, RULES, make_train, check, presets={"authors": AUTHORS_PRESET}),
    AlgoSpec("c-maddpg", "continuous", "constrained MADDPG without leader/follower structure",
             CONSTRAINED_DEFAULTS, HELP, CONSTRAINED_RULES, make_train, check,
             presets={"authors": CONSTRAINED_AUTHORS_PRESET}),
    AlgoSpec("maddpg", "continuous", "plain MADDPG (each actor on its own observation, no constraints)",
             UNCONSTRAINED_DEFAULTS, HELP, RULES, make_train, check, presets={"authors": AUTHORS_PRESET}),
)
