"""CSQ's hyper-parameters (:class:`CSQConfig`): every default, help line and validation rule of the algorithm.

Defaults: the authors' merge CSQ run (docs/algorithms.md). The command line (``python -m train --algo csq``)
registers the options of this dataclass as they are (:func:`jaxsmarl.options.option_table`).
"""

from __future__ import annotations

import dataclasses
import math

from jaxsmarl.hierarchy import is_chain, validate_hierarchy
from jaxsmarl.options import TERMINAL_MASKS, Bool, Choice, Int, Num, PerAgent, Sizes, option

__all__ = ["CSQConfig"]

_PROB = PerAgent(Num(0.0, 1.0, hint="values are probabilities and must lie in [0, 1]"))


@dataclasses.dataclass(frozen=True)
class CSQConfig:
    """Static CSQ hyper-parameters (defaults: the authors' merge CSQ run, docs/algorithms.md)."""

    num_actions: tuple[int, ...] = (5, 5)  # per agent, from the environment
    obs_dim: int = 8  # from the environment
    # from the environment: True when it flags agents absent from an episode (info["alive"], stored as the
    # transitions' `active`); each agent's critic losses then average over the transitions where it drives
    absent_agents: bool = False
    updates_per_step: int = option(1, "gradient updates per loop iteration (authors: 1 per environment step)",
                                   Int(1))
    lr: float = option(1e-3, "Adam learning rate of every reward and cost critic (authors' lr_critic)",
                       Num(0.0, math.inf, lo_open=True, hi_open=True))
    gamma: float = option(0.95, "discount factor", Num(0.0, 1.0))
    tau: float = option(0.01, "soft target update rate: theta' <- (1-tau) theta' + tau theta",
                        Num(0.0, 1.0, lo_open=True))
    target_update_every: int = option(10, "gradient updates between soft target updates (authors' update_rate)",
                                      Int(1))
    batch_size: int = option(64, "transitions per gradient update", Int(1))
    warmup: int = option(512, "transitions stored before the first update (authors' sample_size)", Int(1))
    buffer_size: int = option(500000, "replay capacity per seed (FIFO); never more than total_steps slots are "
                                      "allocated", Int(1))
    cost_threshold: tuple[float, ...] = option(
        (5.0, 5.0), "per-agent cost limits [d_leader, d_follower], one per agent (a single number sets all)",
        PerAgent(Num(hint="use 100 for 'unconstrained'")))
    eps_start: tuple[float, ...] = option(
        (0.1, 0.1), "initial exploration probability [leader, follower], one per agent (a single number sets all)",
        _PROB)
    eps_min: tuple[float, ...] = option(
        (0.0, 0.0), "exploration floor [leader, follower], one per agent (a single number sets all)", _PROB)
    eps_decay: float = option(5e-6, "exploration decrease per environment step (linear)", Num(0.0, 1.0))
    hidden_sizes: tuple[int, ...] = option((64, 64, 64), "hidden layer widths of each critic MLP", Sizes())
    init: str = option("torch", "weight init: torch (the authors' PyTorch default) | lecun (flax default)",
                       Choice(("torch", "lecun")))
    leader_rule: str = option(
        "stackelberg", "stackelberg (paper eq. p14, leader anticipates the follower's best response) | authors "
                       "(their coded max-max over the leader's own Q/G)", Choice(("stackelberg", "authors")))
    infeasible: str = option(
        "min_cost", "when no action satisfies the threshold: min_cost (lowest cost, ties to highest Q) | argmax "
                    "(unconstrained argmax, as the authors)", Choice(("min_cost", "argmax")))
    tie_break: str | None = option(
        None, "equal Q values: first (lowest index) | last (highest, the authors' >= loops) | null (rule default)",
        Choice((None, "first", "last")))
    td_action_state: str = option(
        "next", "state at which the target actions are solved: next (paper, s') | current (authors, s)",
        Choice(("next", "current")))
    td_action_noise: bool = option(False, "epsilon-greedy target actions (authors: true)", Bool())
    td_equilibrium_net: str = option(
        "online", "critics used to solve for the target actions: online (p14) | target", Choice(("online", "target")))
    bootstrap_on_truncation: bool = option(
        True, "true: only an agent's own termination stops bootstrapping (paper); false: the time limit does too "
              "(authors)", Bool())
    terminal_mask: str = option(
        "sample", "which transitions bootstrap: sample (each transition's own terminal flag) | batch_mean (the "
                  "authors' effective rule: every transition bootstraps, discount scaled by the batch's done "
                  "fraction)", Choice(TERMINAL_MASKS))
    # levels of agent indices or "0|1|2" (jaxsmarl.hierarchy); None: the chain 0|1|...|K-1
    hierarchy: str | tuple | None = option(
        None, "who decides before whom: levels of agent indices, '|' between levels, ',' within one, e.g. '0|1|2' "
              "(chain), '0,1|2' (two leaders), '0,1,2' (no hierarchy); null: the chain 0|1|...|K-1 "
              "(docs/algorithms.md)")

    def __post_init__(self):
        if self.terminal_mask not in TERMINAL_MASKS:
            raise ValueError(f"terminal_mask must be one of {', '.join(TERMINAL_MASKS)}, "
                             f"got {self.terminal_mask!r}")
        n = len(self.num_actions)
        for name in ("cost_threshold", "eps_start", "eps_min"):
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name} has {len(getattr(self, name))} entries but there are {n} agents "
                                 f"(num_actions {self.num_actions}); give one per agent")
        if self.hierarchy is not None:
            object.__setattr__(self, "hierarchy", validate_hierarchy(self.hierarchy, n))
            if self.leader_rule == "authors" and not is_chain(self.hierarchy):
                raise ValueError(f"leader_rule='authors' is defined for a chain of single agents; hierarchy "
                                 f"{self.hierarchy} has a level of several agents: use leader_rule='stackelberg'")

    @property
    def levels(self) -> tuple[tuple[int, ...], ...]:
        """The hierarchy as levels of agent indices (the chain 0|1|...|K-1 when none is given)."""
        return tuple((i,) for i in range(self.n_agents)) if self.hierarchy is None else self.hierarchy

    @property
    def n_agents(self) -> int:
        return len(self.num_actions)

    @property
    def resolved_tie_break(self) -> str:
        if self.tie_break is not None:
            return self.tie_break
        return "last" if self.leader_rule == "authors" else "first"
