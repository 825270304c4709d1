"""The study: the paper's scenarios, each with the algorithms it compares (ours first, then the baselines).

Read by the study runner (:mod:`train.experiments`), its figures (:mod:`train.figures`), its report
(:mod:`train.report`) and the committed training records (:mod:`train.records`).
"""

from __future__ import annotations

__all__ = ["STUDY"]

# Scenario -> algorithms, in the paper's order.
STUDY: dict[str, tuple[str, ...]] = {
    "merge": ("csq", "sq"),
    "roundabout": ("csq", "sq"),
    "intersection": ("cs-maddpg", "s-maddpg", "mappo-l", "macpo"),
    "racetrack": ("cs-maddpg", "s-maddpg", "mappo-l", "macpo"),
}
