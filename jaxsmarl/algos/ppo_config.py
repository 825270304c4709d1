"""MAPPO-L's and MACPO's hyper-parameters (:class:`PPOConfig`): every default, help line and validation rule.

Defaults: the MACPO repository's Ant-2x4 scripts (docs/algorithms.md, MAPPO-L and MACPO), adapted to vectorised
rollouts: ``num_envs`` envs x ``rollout_length`` steps per update instead of 16 processes x 1000 steps, so the
minibatch count is a divisor of that sample count, and the multiplier's step size is the repository's config
default (the Ant-2x4 script's 1e-7 freezes lambda). The options marked ``only="mappo-l"`` or ``only="macpo"``
belong to that algorithm's actor update. The command line registers the options of this dataclass
(:func:`jaxsmarl.options.option_table`).
"""

from __future__ import annotations

import dataclasses
import math

from jaxsmarl.options import Bool, Int, Num, option

__all__ = ["PPOConfig"]

_POS = Num(0.0, math.inf, lo_open=True, hi_open=True)
_PROB = Num(0.0, 1.0)


@dataclasses.dataclass(frozen=True)
class PPOConfig:
    """Static hyper-parameters (defaults: the MACPO repository's Ant-2x4 scripts adapted to vectorised rollouts,
    docs/algorithms.md)."""

    n_agents: int = 2  # from the environment
    obs_dim: int = 8  # from the environment
    action_dim: int = 1  # from the environment
    num_actions: int = 0  # from the environment: discrete actions per agent (categorical policy); 0: continuous
    absent_agents: bool = False  # from the environment: info["alive"] flags agents absent from an episode
    rollout_length: int = option(32, "steps per env between updates; one update uses num_envs * rollout_length "
                                     "samples (reference: 16 threads x 1000 steps)", Int(1))
    hidden: int = option(64, "hidden width of every actor and critic (reference hidden_size 64)", Int(1))
    layer_n: int = option(1, "extra hidden layers after the first (reference layer_N 1: two hidden layers)", Int(0))
    feature_norm: bool = option(True, "LayerNorm on the network input (the reference's use_feature_normalization)",
                                Bool())
    obs_norm: bool = option(True, "running mean/std observation normalisation (kept in the training state)", Bool())
    value_norm: bool = option(True, "running normalisation of value targets (the reference's ValueNorm, one per "
                                    "critic)", Bool())
    std_x_coef: float = option(1.0, "std = sigmoid(log_std / std_x_coef) * std_y_coef; log_std starts at "
                                    "std_x_coef", _POS)
    std_y_coef: float = option(0.5, "upper bound of the policy's standard deviation", _POS)
    gamma: float = option(0.99, "discount factor (rewards and costs)", _PROB)
    gae_lambda: float = option(0.95, "GAE lambda (rewards and costs)", _PROB)
    critic_lr: float = option(5e-3, "Adam learning rate of the reward and cost critics", _POS)
    adam_eps: float = option(1e-5, "Adam epsilon", _POS)
    value_clip: float = option(0.2, "value clipping range around the rollout's predictions", _POS)
    huber_delta: float = option(10.0, "Huber loss delta of the critics", _POS)
    value_loss_coef: float = option(1.0, "critic loss weight", Num(0.0))
    max_grad_norm: float = option(10.0, "gradient-norm clip of every network", _POS)
    num_minibatches: int = option(32, "minibatches per pass over one rollout (reference 40; here a divisor of "
                                      "num_envs * rollout_length)", Int(1))
    cost_limit: float = option(0.2, "limit d on the episode cost J_c (per-step cost averaged over agents, summed "
                                    "over the episode)", Num())
    per_agent_cost: bool = option(False, "true: agent i's constraint uses its own episode cost instead of the agent "
                                         "average", Bool())
    sequential: bool = option(True, "true: agents updated in a random order, each surrogate weighted by the "
                                    "previous agents' ratio product (reference, HAPPO-style); false: simultaneous "
                                    "update", Bool())
    actor_lr: float = option(9e-5, "Adam learning rate of the actors", _POS, only="mappo-l")
    clip: float = option(0.2, "PPO ratio clip epsilon", _POS, only="mappo-l")
    ppo_epochs: int = option(5, "passes over each rollout", Int(1), only="mappo-l")
    entropy_coef: float = option(0.01, "entropy bonus weight", Num(0.0), only="mappo-l")
    lambda_init: float = option(0.78, "initial Lagrange multiplier (reference 0.78)", Num(0.0), only="mappo-l")
    lambda_lr: float = option(5e-4, "multiplier step size, updated every minibatch (MACPO-repo config default "
                                    "5e-4; the Ant-2x4 script's 1e-7 freezes lambda)", Num(0.0), only="mappo-l")
    kl_threshold: float = option(0.0065, "trust region delta on the mean KL (reference Ant-2x4 0.0065)", _POS,
                                 only="macpo")
    cg_iters: int = option(10, "conjugate-gradient iterations", Int(1), only="macpo")
    ls_steps: int = option(10, "line-search candidates", Int(1), only="macpo")
    ls_fraction: float = option(0.5, "line-search shrink factor per candidate",
                                Num(0.0, 1.0, lo_open=True, hi_open=True), only="macpo")
    fraction_coef: float = option(0.27, "first line-search step size (reference Ant-2x4 0.27)", _POS, only="macpo")
    fvp_damping: float = option(0.1, "damping added to the Fisher-vector product (reference 0.1)", Num(0.0),
                                only="macpo")

    @property
    def share_dim(self) -> int:
        return self.n_agents * self.obs_dim
