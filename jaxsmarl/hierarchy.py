"""Hierarchies of K agents as data: who decides before whom (the paper's multi-agent expansion).

A hierarchy is a tuple of levels, each a tuple of agent indices, first level first (docs/algorithms.md,
"Hierarchies of K agents"):

* ``((0,), (1,), (2,))``: a vertical chain, ``a_k = mu_k(o_k, a_1, ..., a_{k-1})`` (the paper's vertical expansion);
* ``((0, 1), (2, 3))``: two leaders and two followers; every follower sees both leaders' actions and the agents on
  one level play a Nash equilibrium among themselves (the paper's horizontal expansion);
* ``((0, 1, 2),)``: no hierarchy, every agent simultaneous (the usual MARL baseline).

The two-agent ``((0,), (1,))`` is the paper's leader-follower game. On the command line a hierarchy is written
with ``|`` between levels and ``,`` between the agents of a level: ``"0|1|2"``, ``"0,1|2,3"``, ``"0,1,2"``; the
words ``chain`` and ``flat`` name the two extremes for any K. Agents on a level are stored in increasing order
(a level is a set; the order only fixes the index used to break exact ties).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

__all__ = ["Hierarchy", "chain", "flat", "default_hierarchy", "parse_hierarchy", "validate_hierarchy",
           "format_hierarchy", "is_chain", "agent_order", "EXPECTED_FORM"]

Hierarchy = tuple[tuple[int, ...], ...]

EXPECTED_FORM = ("levels of agent indices, first level first, each agent on exactly one level: '|' between levels "
                 "and ',' between the agents of a level, e.g. '0|1|2' (vertical chain), '0,1|2,3' (two leaders, "
                 "two followers), '0,1,2' (no hierarchy), or the words 'chain' / 'flat'")


def chain(num_agents: int) -> Hierarchy:
    """The vertical chain ``0 | 1 | ... | K-1`` (agent 0 leads)."""
    return tuple((i,) for i in range(_count(num_agents)))


def flat(num_agents: int) -> Hierarchy:
    """No hierarchy: all K agents on one level."""
    return (tuple(range(_count(num_agents))),)


def default_hierarchy(num_agents: int) -> Hierarchy:
    """The hierarchy used when none is given: the vertical chain in agent order, which for two agents is the
    paper's leader (agent 0) and follower (agent 1)."""
    return chain(num_agents)


def _count(num_agents: Any) -> int:
    if isinstance(num_agents, bool) or not isinstance(num_agents, int) or num_agents < 1:
        raise ValueError(f"the number of agents must be an integer >= 1, got {num_agents!r}")
    return num_agents


def parse_hierarchy(text: str, num_agents: int) -> Hierarchy:
    """A hierarchy from its command-line form (``"0|1|2"``, ``"0,1|2,3"``, ``"chain"``, ``"flat"``), validated
    for ``num_agents`` agents."""
    k = _count(num_agents)
    if not isinstance(text, str):
        raise ValueError(f"hierarchy must be a string, got {type(text).__name__}; expected {EXPECTED_FORM}")
    s = text.strip()
    if s == "chain":
        return chain(k)
    if s == "flat":
        return flat(k)
    levels = []
    for part in s.split("|"):
        items = [x.strip() for x in part.split(",")]
        if any(not x.lstrip("-").isdigit() for x in items):
            raise ValueError(f"hierarchy {text!r} is not understood (level {part.strip()!r} is not a list of agent "
                             f"indices); expected {EXPECTED_FORM}")
        levels.append(tuple(int(x) for x in items))
    return validate_hierarchy(levels, k)


def validate_hierarchy(levels: Any, num_agents: int) -> Hierarchy:
    """``levels`` (a hierarchy string, or a sequence of sequences of agent indices) checked for ``num_agents``
    agents: every agent ``0..K-1`` on exactly one level, no empty level. Returns the normalised tuple form."""
    k = _count(num_agents)
    if isinstance(levels, str):
        return parse_hierarchy(levels, k)
    shown = format_hierarchy(levels) if _is_nested_ints(levels) else repr(levels)
    if not _is_nested_ints(levels):
        raise ValueError(f"hierarchy {shown} is not a sequence of levels of agent indices; expected {EXPECTED_FORM}")
    if len(levels) == 0 or any(len(level) == 0 for level in levels):
        raise ValueError(f"hierarchy {shown!r} has an empty level; expected {EXPECTED_FORM}")
    seen: list[int] = [a for level in levels for a in level]
    bad = sorted({a for a in seen if not 0 <= a < k})
    if bad:
        raise ValueError(f"hierarchy {shown!r} names agent(s) {bad} out of range: with {k} agents the indices are "
                         f"0..{k - 1}; expected {EXPECTED_FORM}")
    repeated = sorted({a for a in seen if seen.count(a) > 1})
    if repeated:
        raise ValueError(f"hierarchy {shown!r} repeats agent(s) {repeated}; each agent is on exactly one level; "
                         f"expected {EXPECTED_FORM}")
    missing = sorted(set(range(k)) - set(seen))
    if missing:
        raise ValueError(f"hierarchy {shown!r} misses agent(s) {missing} of 0..{k - 1}; each agent is on exactly "
                         f"one level; expected {EXPECTED_FORM}")
    return tuple(tuple(sorted(int(a) for a in level)) for level in levels)


def _is_nested_ints(levels: Any) -> bool:
    if isinstance(levels, (str, bytes)) or not isinstance(levels, Sequence):
        return False
    for level in levels:
        if isinstance(level, (str, bytes)) or not isinstance(level, Sequence):
            return False
        if not all(isinstance(a, int) and not isinstance(a, bool) for a in level):
            return False
    return True


def format_hierarchy(levels: Sequence[Sequence[int]]) -> str:
    """The command-line form: ``((0, 1), (2,))`` -> ``"0,1|2"``."""
    return "|".join(",".join(str(a) for a in level) for level in levels)


def is_chain(levels: Hierarchy) -> bool:
    """True when every level holds one agent (a vertical chain, in any agent order)."""
    return all(len(level) == 1 for level in levels)


def agent_order(levels: Hierarchy) -> tuple[int, ...]:
    """The agents in decision order: level by level, increasing index within a level."""
    return tuple(a for level in levels for a in level)
