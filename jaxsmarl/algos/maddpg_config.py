"""CS-MADDPG's hyper-parameters (:class:`MADDPGConfig`): every default, help line and validation rule.

Defaults: the authors' intersection CS-MADDPG run (docs/algorithms.md). ``stackelberg`` and ``constrained`` pick the
variant (CS-MADDPG, S-MADDPG, C-MADDPG, MADDPG); the options marked ``only="constrained"`` exist only with cost
critics. ``n_agents`` and ``hierarchy`` (:mod:`jaxsmarl.hierarchy`) give K agents and who decides before whom; the
per-agent options then hold K values. The command line registers the options of this dataclass
(:func:`jaxsmarl.options.option_table`).
"""

from __future__ import annotations

import dataclasses
import math

from jaxsmarl.hierarchy import chain, flat, format_hierarchy, validate_hierarchy
from jaxsmarl.options import TERMINAL_MASKS, Bool, Choice, Int, Num, PerAgent, Sizes, option

__all__ = ["MADDPGConfig"]

_NOISE = PerAgent(Num(0.0, math.inf, hint="a standard deviation, >= 0"))
_PROB = PerAgent(Num(0.0, 1.0, hint="values are probabilities and must lie in [0, 1]"))
_POS = Num(0.0, math.inf, lo_open=True, hi_open=True)


@dataclasses.dataclass(frozen=True)
class MADDPGConfig:
    """Static hyper-parameters (defaults: the authors' intersection CS-MADDPG run, docs/algorithms.md)."""

    action_dim: int = 1  # per agent, from the environment
    obs_dim: int = 8  # from the environment
    max_action: float = 1.0
    n_agents: int = 2  # from the environment
    # True: the hierarchy (default the chain 0|1|...|K-1) conditions each actor on the actions of the levels above
    # and sends each actor's gradient through the actors below; False: no hierarchy (every agent on one level)
    stackelberg: bool = True
    constrained: bool = True  # cost critics + Lagrange multipliers
    updates_per_step: int = option(1, "gradient updates per loop iteration (authors: 1 per environment step)",
                                   Int(1))
    lr_actor: float = option(1e-4, "Adam learning rate of both actors", _POS)
    lr_critic: float = option(1e-3, "Adam learning rate of every reward and cost critic", _POS)
    gamma: float = option(0.95, "discount factor", Num(0.0, 1.0))
    tau: float = option(0.01, "soft target update rate: theta' <- (1-tau) theta' + tau theta (all actors and "
                              "critics)", Num(0.0, 1.0, lo_open=True))
    target_update_every: int = option(10, "gradient updates between soft target updates (authors' update_rate)",
                                      Int(1))
    batch_size: int = option(256, "transitions per gradient update", Int(1))
    warmup: int = option(512, "transitions stored before the first update (authors' sample_size)", Int(1))
    buffer_size: int = option(500000, "replay capacity per seed (FIFO); never more than total_steps slots are "
                                      "allocated", Int(1))
    noise_start: tuple[float, ...] = option(
        (0.1, 0.1), "initial Gaussian action-noise std [leader, follower] (a single number sets both)", _NOISE)
    noise_min: tuple[float, ...] = option((0.0, 0.0), "floor of the action-noise std [leader, follower]", _NOISE)
    eps_start: tuple[float, ...] = option(
        (0.1, 0.1), "initial probability of a uniform random action [leader, follower]", _PROB)
    eps_min: tuple[float, ...] = option((0.0, 0.0), "floor of the random-action probability [leader, follower]",
                                        _PROB)
    explore_decay: float = option(
        5e-7, "decrease of noise std and random-action probability per environment step (linear)", Num(0.0, 1.0))
    hidden_sizes: tuple[int, ...] = option((64, 64, 64), "hidden layer widths of every actor and critic MLP",
                                           Sizes())
    init: str = option("torch", "weight init: torch (the authors' PyTorch default) | lecun (flax default)",
                       Choice(("torch", "lecun")))
    critic_input: str = option(
        "joint", "state seen by the centralized critics: joint (paper, s = both observations) | own (authors, the "
                 "agent's own observation)", Choice(("joint", "own")))
    bootstrap_on_truncation: bool = option(
        True, "true: only an agent's own termination stops bootstrapping (paper); false: the time limit does too "
              "(authors)", Bool())
    actor_order: str = option(
        "simultaneous", "simultaneous: both actors step from the same parameters (Algorithm 2) | sequential: the "
                        "leader steps first and the follower's actor loss and multiplier see the stepped leader "
                        "actor (the authors' leader.train() then follower.train())",
        Choice(("simultaneous", "sequential")))
    terminal_mask: str = option(
        "sample", "which transitions bootstrap: sample (each transition's own terminal flag) | batch_mean (the "
                  "authors' effective rule: every transition bootstraps, discount scaled by the batch's done "
                  "fraction), for the reward and the cost critics", Choice(TERMINAL_MASKS))
    # levels of agent indices or "0|1|2" (jaxsmarl.hierarchy); None: the chain (stackelberg) or one level
    hierarchy: str | tuple | None = option(
        None, "who decides before whom (s-maddpg, cs-maddpg): levels of agent indices, '|' between levels, ',' within "
              "one, e.g. '0|1|2' (chain), '0,1|2' (two leaders), '0,1,2' (no hierarchy); null: the chain "
              "0|1|...|K-1 (maddpg, c-maddpg: no hierarchy) (docs/algorithms.md)")
    cost_threshold: tuple[float, ...] = option(
        (5.0, 5.0), "per-agent cost limits [d_leader, d_follower] on the cost critics (a single number sets both)",
        PerAgent(Num(hint="the cost critics estimate discounted episode costs")), only="constrained")
    lambda_rule: str = option(
        "dual", "Lagrange multiplier rule: dual (paper p22: lambda += lr (G - d), projected to [0, lambda_max], "
                "penalty lambda (G - d)) | authors (lambda += lr relu(G - d), never decreases, hinge penalty)",
        Choice(("dual", "authors")), only="constrained")
    lr_lambda: float = option(1e-3, "multiplier step size (the paper's slower timescale beta_i)",
                              Num(0.0, math.inf, hi_open=True), only="constrained")
    lambda_init: float = option(0.0, "initial multiplier of both agents (authors' configs: 0)",
                                Num(0.0, math.inf, hi_open=True), only="constrained")
    lambda_max: float = option(100.0, "upper bound of the multipliers (authors' configs: 100)",
                               Num(0.0, math.inf, hi_open=True), only="constrained")

    def __post_init__(self):
        if self.critic_input not in ("joint", "own"):
            raise ValueError(f"critic_input must be 'joint' or 'own', got {self.critic_input!r}")
        if self.init not in ("torch", "lecun"):
            raise ValueError(f"init must be 'torch' or 'lecun', got {self.init!r}")
        if self.terminal_mask not in TERMINAL_MASKS:
            raise ValueError(f"terminal_mask must be one of {', '.join(TERMINAL_MASKS)}, "
                             f"got {self.terminal_mask!r}")
        if isinstance(self.n_agents, bool) or not isinstance(self.n_agents, int) or self.n_agents < 1:
            raise ValueError(f"n_agents must be an integer >= 1, got {self.n_agents!r}")
        for name in ("cost_threshold", "noise_start", "noise_min", "eps_start", "eps_min"):
            if len(getattr(self, name)) != self.n_agents:
                raise ValueError(f"{name} needs one value per agent ({self.n_agents}), got {getattr(self, name)}")
        if self.hierarchy is not None:
            levels = validate_hierarchy(self.hierarchy, self.n_agents)
            if not self.stackelberg and len(levels) > 1:
                raise ValueError(f"hierarchy '{format_hierarchy(levels)}' has several levels but this variant has no "
                                 "leaders and followers (stackelberg=False): give one level, e.g. "
                                 f"'{format_hierarchy(flat(self.n_agents))}', or use the Stackelberg variant")
            object.__setattr__(self, "hierarchy", levels)

    @property
    def levels(self) -> tuple[tuple[int, ...], ...]:
        """The hierarchy as levels of agent indices: the one given, else the chain 0|1|...|K-1 (Stackelberg) or one
        level of all agents."""
        if self.hierarchy is not None:
            return self.hierarchy
        return chain(self.n_agents) if self.stackelberg else flat(self.n_agents)

    def above(self, agent: int) -> tuple[int, ...]:
        """The agents on the levels above ``agent``'s, in decision order: the actions its actor reads."""
        out: list[int] = []
        for level in self.levels:
            if agent in level:
                return tuple(out)
            out += list(level)
        raise ValueError(f"agent {agent} is not in the hierarchy {format_hierarchy(self.levels)}")

    def actor_in_dim(self, agent: int) -> int:
        """Inputs of ``agent``'s actor: its observation and the actions of the levels above it."""
        return self.obs_dim + self.action_dim * len(self.above(agent))

    @property
    def n_kinds(self) -> int:
        return 2 if self.constrained else 1

    @property
    def critic_obs_dim(self) -> int:
        return self.n_agents * self.obs_dim if self.critic_input == "joint" else self.obs_dim
