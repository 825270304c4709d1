"""The authors' recorded results and the paper's claims, as reference points for our figures and RESULTS.md.

Numbers: the authors' shipped records (docs/results.md; per-run statistics of the shipped ``.npy`` records: mean
over the last ceil(10%) of each seed's training episodes; returns include rewards earned after an agent's own
termination, as in our episode returns). One value per authors' seed; ``None`` where the record is missing.
"""

from __future__ import annotations

import numpy as np

__all__ = ["AUTHORS", "PAPER_CLAIMS", "CODE_DIFFERENCES", "authors_values", "authors_summary"]

# (scenario, our algorithm) -> {"run": the authors' folder, "steps": their training budget (env steps per seed,
# None where unknown), "note": caveats, field: [value per seed]}.
AUTHORS: dict[tuple[str, str], dict] = {
    ("merge", "csq"): {
        "run": "merge_env_result/exp1 (CSQ, d=5)", "steps": 20000, "note": "",
        "leader_return": [21.96, 30.48, 31.84], "follower_return": [33.74, 25.56, 26.84],
        "total_return": [55.69, 56.04, 58.67], "crash": [0.005, 0.000, 0.000],
        # merge records leader_arrive == follower_arrive == not crash ("both arrived")
        "leader_arrived": [0.99, 1.00, 1.00], "follower_arrived": [0.99, 1.00, 1.00],
    },
    ("merge", "sq"): {
        "run": "merge_env_result/exp1_bilevel ('Bi-AC' = CSQ, d=100)", "steps": 20000, "note": "",
        "leader_return": [30.46, 29.05, 27.96], "follower_return": [25.48, 27.73, 23.41],
        "total_return": [55.94, 56.78, 51.37], "crash": [0.021, 0.031, 0.115],
        "leader_arrived": [0.98, 0.97, 0.89], "follower_arrived": [0.98, 0.97, 0.89],
    },
    ("roundabout", "csq"): {
        "run": "roundabout_env_result/exp1 (CSQ, d=5)", "steps": 10000, "note": "",
        "leader_return": [34.64, 37.35, 35.63], "follower_return": [31.94, 30.77, 30.63],
        "total_return": [66.58, 68.13, 66.27], "crash": [0.014, 0.028, 0.042],
        "leader_arrived": [1.00, 0.97, 1.00], "follower_arrived": [1.00, 0.97, 0.96],
    },
    ("roundabout", "sq"): {
        "run": "roundabout_env_result/exp1_bilevel ('Bi-AC' = CSQ, d=2/2/100)", "steps": 10000,
        "note": "crash recorded for seed_2 only; seeds 0 and 1 used d=2 (tighter than CSQ's d=5)",
        "leader_return": [33.44, 32.42, 34.63], "follower_return": [29.70, 28.69, 29.29],
        "total_return": [63.14, 61.11, 63.91], "crash": [None, None, 0.071],
        "leader_arrived": [0.93, 0.89, 0.93], "follower_arrived": [0.93, 0.89, 0.93],
    },
    ("intersection", "cs-maddpg"): {
        "run": "intersection_env_result/exp1 (CS-MADDPG, d=5/5/4)", "steps": 20000,
        "note": "crash not recorded; arrival recorded as first arrival only",
        "leader_return": [14.91, 19.23, 14.91], "follower_return": [14.53, 14.59, 14.33],
        "total_return": [29.44, 33.82, 29.24],
    },
    ("intersection", "s-maddpg"): {
        "run": "intersection_env_result/exp1_bilevel (Bi-AC)", "steps": 20000,
        "note": "crash not recorded; arrival recorded as first arrival only",
        "leader_return": [16.15, 15.32, 16.49], "follower_return": [15.22, 14.22, 14.29],
        "total_return": [31.36, 29.53, 30.78],
    },
    ("intersection", "macpo"): {
        "run": "intersection_env_result/algorithm_compare/macpo/seed_1..3", "steps": None,
        "note": "about 4.7x more episodes than CS-MADDPG; crash not recorded; code not shipped",
        "leader_return": [18.57, 18.70, 18.70], "follower_return": [15.26, 14.87, 15.48],
        "total_return": [33.83, 33.58, 34.17],
    },
    ("intersection", "mappo-l"): {
        "run": "intersection_env_result/algorithm_compare/exp_mappo_l_1..3", "steps": None,
        "note": "crash recorded for _1 only (_2's is a copy of _1's); reward definition may differ; code not shipped",
        "leader_return": [16.55, 6.72, 9.38], "follower_return": [4.27, 15.31, 14.92],
        "total_return": [20.83, 22.03, 24.30], "crash": [0.000, None, None],
    },
    ("racetrack", "cs-maddpg"): {
        "run": "racetrack_env_result/exp1 (CS-MADDPG, d=1)", "steps": 500000,
        "note": "crash counts mutual collisions only (not off-road)",
        "leader_return": [68.35, 94.73, 105.21], "follower_return": [66.83, 96.90, 103.51],
        "total_return": [135.18, 191.63, 208.72], "crash": [0.018, 0.088, 0.747],
    },
    ("racetrack", "s-maddpg"): {
        "run": "racetrack_env_result/exp1_bilevel (Bi-AC)", "steps": 500000,
        "note": "crash counts mutual collisions only (not off-road)",
        "leader_return": [59.30, 34.37, 41.53], "follower_return": [58.77, 32.72, 44.76],
        "total_return": [118.06, 67.09, 86.29], "crash": [0.311, 0.658, 0.152],
    },
    ("racetrack", "macpo"): {
        "run": "racetrack_env_result/macpo/exp_4/seed_0..2 (plotted)", "steps": None,
        "note": "35k-41k episodes per seed; code not shipped",
        "leader_return": [38.08, 34.83, 38.67], "follower_return": [39.17, 34.17, 39.88],
        "total_return": [77.24, 69.00, 78.55], "crash": [0.116, 0.232, 0.194],
    },
    ("racetrack", "mappo-l"): {
        "run": "racetrack_env_result/mappo_l/exp_4/seed_0..2 (plotted)", "steps": None,
        "note": "seed_2 is a truncated copy of seed_1 (really 2 runs); code not shipped",
        "leader_return": [30.89, 17.92, 29.79], "follower_return": [30.47, 17.20, 26.53],
        "total_return": [61.36, 35.12, 56.31], "crash": [0.308, 0.024, 0.271],
    },
}

PAPER_CLAIMS = {
    "merge": "CSQ beats Bi-AC in reward after convergence and is 100% safe, while Bi-AC still crashes in about 10% "
             "of episodes (paper, merge section).",
    "roundabout": "CSQ attains higher rewards and safety rates than Bi-AC (paper, roundabout section).",
    "intersection": "CS-MADDPG reaches rewards very close to MACPO's with a slight safety advantage and converges "
                    "faster (paper, intersection section).",
    "racetrack": "CS-MADDPG reaches rewards several times greater than the baselines and covers longer distances "
                 "(paper, racetrack section).",
}

# Known differences between the paper's text and the authors' code (docs/algorithms.md), and which side the
# shipped configurations follow. Keys whose value in our run config tells which side is used are checked by
# train.report against the runs' config.json.
CODE_DIFFERENCES = [
    ("leader_rule", "stackelberg",
     "CSQ leader: the paper's Stackelberg rule (leader anticipates the follower's best response, eq. p14); the "
     "authors coded a max-max of the leader's own Q over joint actions among pairs its own cost critic deems safe "
     "(`leader_rule=authors`)."),
    ("td_action_state", "next",
     "CSQ TD target: joint action solved at s' as in the paper; the authors' code solves it at the current "
     "observation (`td_action_state=current`)."),
    ("td_action_noise", False,
     "CSQ TD target actions without exploration noise (paper); the authors' code keeps epsilon-greedy noise "
     "(`td_action_noise=true`)."),
    ("bootstrap_on_truncation", True,
     "Only an agent's own termination stops bootstrapping (paper); the authors also cut at the time limit."),
    (None, None,
     "The cost thresholds are as the authors ran them (d = 5 for CSQ, d = 1 on the racetrack), at or above the "
     "largest possible discounted cost, so the constraints are nearly inactive (docs/algorithms.md, 'Why the "
     "authors' thresholds barely bind')."),
    (None, None,
     "The unconstrained baselines are the authors': 'Bi-AC' in merge / roundabout is CSQ with d = 100 and an "
     "exploration floor of 0.05 (our `sq`); on the continuous scenarios it is Stackelberg MADDPG without a cost "
     "critic (our `s-maddpg`)."),
    (None, None,
     "Rewards, costs and termination are the authors' coded ones (docs/scenarios.md), e.g. the roundabout's +5 on "
     "every step on the exit road and merge's one-shot arrival bonus."),
    (None, None,
     "The authors' MACPO / MAPPO-L code is not shipped; our implementations follow the published algorithms "
     "(docs/algorithms.md), so their reference numbers are not like-for-like."),
]


def authors_values(scenario: str, algo: str, field: str) -> list[float]:
    """The authors' per-seed last-10% values of ``field`` (missing seeds dropped); [] when not recorded."""
    ref = AUTHORS.get((scenario, algo), {})
    return [float(v) for v in ref.get(field, []) if v is not None]


def authors_summary(scenario: str, algo: str, field: str) -> tuple[float, float, int] | None:
    """``(mean, std, n)`` over the authors' seeds (population std, ddof=0), or None."""
    v = authors_values(scenario, algo, field)
    if not v:
        return None
    return float(np.mean(v)), float(np.std(v)), len(v)
