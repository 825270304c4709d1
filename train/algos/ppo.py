"""MAPPO-L and MACPO (Gu et al. 2023), the paper's on-policy safe-MARL baselines: Gaussian policies on the
continuous scenarios, categorical ones on the discrete scenarios, K agents where the scenario has them (no
hierarchy: ``--hierarchy`` is accepted only as the flat one).

Every key's default, help line and rule is a field of :class:`jaxsmarl.algos.ppo_config.PPOConfig` (the MACPO
repository's Ant-2x4 scripts adapted to vectorised rollouts, docs/algorithms.md); per-scenario values (envs,
rollout length, minibatches, budget) are in ``train/configs/<scenario>_<algo>.json``.
"""

from __future__ import annotations

import math

from jaxsmarl.algos.ppo_config import PPOConfig
from jaxsmarl.options import option_table
from train.config import AlgoSpec, register

# Every key, default, help line and rule: the options of PPOConfig (the shared ones and the algorithm's own).
MAPPOL_DEFAULTS, MAPPOL_HELP, MAPPOL_RULES = option_table(PPOConfig, ("mappo-l",))
MACPO_DEFAULTS, MACPO_HELP, MACPO_RULES = option_table(PPOConfig, ("macpo",))


def check(cfg: dict) -> None:
    cycle = cfg["num_envs"] * cfg["rollout_length"]
    for k in ("total_steps", "chunk_steps"):
        if cfg[k] % cycle:
            raise ValueError(f"'{k}' ({cfg[k]}) must be a multiple of num_envs * rollout_length ({cycle}): a chunk "
                             f"holds whole rollout+update cycles; "
                             f"e.g. set {k} to {max(1, round(cfg[k] / cycle)) * cycle}")
    if cycle % cfg["num_minibatches"]:
        raise ValueError(f"num_envs * rollout_length ({cycle}) must be a multiple of num_minibatches "
                         f"({cfg['num_minibatches']}): every minibatch has the same size")


def make_agent(config: dict, env):
    from jaxsmarl.algos.macpo import MACPO
    from jaxsmarl.algos.mappo_l import MAPPOL

    fields = PPOConfig.__dataclass_fields__
    kw = {k: v for k, v in config.items() if k in fields}
    kw.update(n_agents=int(env.num_agents), obs_dim=math.prod(env.obs_shape[1:]),
              absent_agents=bool(getattr(env, "has_absent_agents", False)))
    if env.discrete:
        kw.update(num_actions=int(env.num_actions), action_dim=1)
    else:
        kw.update(action_dim=int(env.action_shape[-1]))
    cls = MAPPOL if config["algo"] == "mappo-l" else MACPO
    return cls(PPOConfig(**kw))


register(
    AlgoSpec("mappo-l", "both", "MAPPO-Lagrangian (Gu et al. 2023): PPO-clip on A_r - lambda A_c, "
             "sequential agent updates", MAPPOL_DEFAULTS, MAPPOL_HELP, MAPPOL_RULES, make_agent, "onpolicy", check,
             seeds_in_sequence_on_cpu=True, flat_only=True),
    AlgoSpec("macpo", "both", "MACPO (Gu et al. 2023): constrained trust-region (CPO) steps, sequential "
             "agent updates", MACPO_DEFAULTS, MACPO_HELP, MACPO_RULES, make_agent, "onpolicy", check,
             seeds_in_sequence_on_cpu=True, flat_only=True),
)
