"""MAPPO-L and MACPO (Gu et al. 2023), the paper's on-policy safe-MARL baselines for the continuous scenarios.

Defaults: the MACPO repository's Ant-2x4 scripts (docs/algorithms.md, MAPPO-L and MACPO), adapted to vectorised rollouts: instead of
16 processes x 1000 steps per update, ``num_envs`` envs x ``rollout_length`` steps (set per scenario in
``train/configs/<scenario>_<algo>.json``); the 40 minibatches then hold proportionally more samples.
"""

from __future__ import annotations

import math

from train.config import AlgoSpec, Bool, Int, Num, register

POS = Num(0.0, math.inf, lo_open=True, hi_open=True)
PROB = Num(0.0, 1.0)

SHARED = {
    "rollout_length": 32, "hidden": 64, "layer_n": 1, "feature_norm": True, "obs_norm": True, "value_norm": True,
    "std_x_coef": 1.0, "std_y_coef": 0.5, "gamma": 0.99, "gae_lambda": 0.95, "critic_lr": 5e-3, "adam_eps": 1e-5,
    "value_clip": 0.2, "huber_delta": 10.0, "value_loss_coef": 1.0, "max_grad_norm": 10.0, "num_minibatches": 32,
    "cost_limit": 0.2, "per_agent_cost": False, "sequential": True,
}
SHARED_HELP = {
    "rollout_length": "steps per env between updates; one update uses num_envs * rollout_length samples "
                      "(reference: 16 threads x 1000 steps)",
    "hidden": "hidden width of every actor and critic (reference hidden_size 64)",
    "layer_n": "extra hidden layers after the first (reference layer_N 1: two hidden layers)",
    "feature_norm": "LayerNorm on the network input (the reference's use_feature_normalization)",
    "obs_norm": "running mean/std observation normalisation (kept in the training state)",
    "value_norm": "running normalisation of value targets (the reference's ValueNorm, one per critic)",
    "std_x_coef": "std = sigmoid(log_std / std_x_coef) * std_y_coef; log_std starts at std_x_coef",
    "std_y_coef": "upper bound of the policy's standard deviation",
    "gamma": "discount factor (rewards and costs)",
    "gae_lambda": "GAE lambda (rewards and costs)",
    "critic_lr": "Adam learning rate of the reward and cost critics",
    "adam_eps": "Adam epsilon",
    "value_clip": "value clipping range around the rollout's predictions",
    "huber_delta": "Huber loss delta of the critics",
    "value_loss_coef": "critic loss weight",
    "max_grad_norm": "gradient-norm clip of every network",
    "num_minibatches": "minibatches per pass over one rollout (reference 40; here a divisor of num_envs * rollout_length)",
    "cost_limit": "limit d on the episode cost J_c (per-step cost averaged over agents, summed over the episode)",
    "per_agent_cost": "true: agent i's constraint uses its own episode cost instead of the agent average",
    "sequential": "true: agents updated in a random order, each surrogate weighted by the previous agents' ratio "
                  "product (reference, HAPPO-style); false: simultaneous update",
}
SHARED_RULES = {
    "rollout_length": Int(1), "hidden": Int(1), "layer_n": Int(0), "feature_norm": Bool(), "obs_norm": Bool(),
    "value_norm": Bool(), "std_x_coef": POS, "std_y_coef": POS, "gamma": PROB, "gae_lambda": PROB,
    "critic_lr": POS, "adam_eps": POS, "value_clip": POS, "huber_delta": POS, "value_loss_coef": Num(0.0),
    "max_grad_norm": POS, "num_minibatches": Int(1), "cost_limit": Num(), "per_agent_cost": Bool(),
    "sequential": Bool(),
}

MAPPOL_DEFAULTS = {**SHARED, "actor_lr": 9e-5, "clip": 0.2, "ppo_epochs": 5, "entropy_coef": 0.01,
                   "lambda_init": 0.78, "lambda_lr": 5e-4}
MAPPOL_HELP = {**SHARED_HELP, "actor_lr": "Adam learning rate of the actors", "clip": "PPO ratio clip epsilon",
               "ppo_epochs": "passes over each rollout", "entropy_coef": "entropy bonus weight",
               "lambda_init": "initial Lagrange multiplier (reference 0.78)",
               "lambda_lr": "multiplier step size, updated every minibatch (MACPO-repo config default 5e-4; the Ant-2x4 script's 1e-7 freezes lambda)"}
MAPPOL_RULES = {**SHARED_RULES, "actor_lr": POS, "clip": POS, "ppo_epochs": Int(1), "entropy_coef": Num(0.0),
                "lambda_init": Num(0.0), "lambda_lr": Num(0.0)}

MACPO_DEFAULTS = {**SHARED, "kl_threshold": 0.0065, "cg_iters": 10, "ls_steps": 10, "ls_fraction": 0.5,
                  "fraction_coef": 0.27, "fvp_damping": 0.1}
MACPO_HELP = {**SHARED_HELP, "kl_threshold": "trust region delta on the mean KL (reference Ant-2x4 0.0065)",
              "cg_iters": "conjugate-gradient iterations", "ls_steps": "line-search candidates",
              "ls_fraction": "line-search shrink factor per candidate",
              "fraction_coef": "first line-search step size (reference Ant-2x4 0.27)",
              "fvp_damping": "damping added to the Fisher-vector product (reference 0.1)"}
MACPO_RULES = {**SHARED_RULES, "kl_threshold": POS, "cg_iters": Int(1), "ls_steps": Int(1),
               "ls_fraction": Num(0.0, 1.0, lo_open=True, hi_open=True), "fraction_coef": POS,
               "fvp_damping": Num(0.0)}


def check(cfg: dict) -> None:
    cycle = cfg["num_envs"] * cfg["rollout_length"]
    for k in ("total_steps", "chunk_steps"):
        if cfg[k] % cycle:
            raise ValueError(f"'{k}' ({cfg[k]}) must be a multiple of num_envs * rollout_length ({cycle}): a chunk "
                             f"holds whole rollout+update cycles; e.g. set {k} to {max(1, round(cfg[k] / cycle)) * cycle}")
    if cycle % cfg["num_minibatches"]:
        raise ValueError(f"num_envs * rollout_length ({cycle}) must be a multiple of num_minibatches "
                         f"({cfg['num_minibatches']}): every minibatch has the same size")


def make_agent(config: dict, env):
    from jaxsmarl.algos.macpo import MACPO
    from jaxsmarl.algos.mappo_l import MAPPOL
    from jaxsmarl.algos.ppo_base import PPOConfig

    if env.discrete:
        raise ValueError(f"'{config['algo']}' needs continuous actions; use intersection or racetrack")
    fields = PPOConfig.__dataclass_fields__
    kw = {k: v for k, v in config.items() if k in fields}
    kw.update(n_agents=int(env.num_agents), obs_dim=int(env.obs_shape[-1]), action_dim=int(env.action_shape[-1]))
    cls = MAPPOL if config["algo"] == "mappo-l" else MACPO
    return cls(PPOConfig(**kw))


def make_train(config: dict, env=None):
    from train.loop import make_env
    from train.onpolicy import make_onpolicy_train

    env = make_env(config["scenario"]) if env is None else env
    return make_onpolicy_train(config, env, make_agent(config, env[0]))


register(
    AlgoSpec("mappo-l", "continuous", "MAPPO-Lagrangian (Gu et al. 2023): PPO-clip on A_r - lambda A_c, "
             "sequential agent updates", MAPPOL_DEFAULTS, MAPPOL_HELP, MAPPOL_RULES, make_train, check),
    AlgoSpec("macpo", "continuous", "MACPO (Gu et al. 2023): constrained trust-region (CPO) steps, sequential "
             "agent updates", MACPO_DEFAULTS, MACPO_HELP, MACPO_RULES, make_train, check),
)
