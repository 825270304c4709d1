"""What ``python -m train`` tells the user when a run has finished: where it went, what is in it, what to run next."""

from __future__ import annotations

import os
import shlex

from train.config import TRAFFIC_SCENARIOS

__all__ = ["FILES", "next_steps"]

# Run folder entries (train.run) and what each holds, in the order they are listed.
FILES = {
    "config.json": "the resolved configuration",
    "episodes.csv": "every training episode of every seed (returns, costs, crash, arrivals, length)",
    "summary.json": "last-10% statistics with 95% intervals across seeds, timing, greedy evaluation",
    "eval.csv": "the greedy evaluation episodes per seed",
    "checkpoints": "the whole training state (all seeds), newest",
}


def _size(path: str) -> str:
    n = os.path.getsize(path)
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return ""


def next_steps(out: str, config: dict) -> str:
    """The closing message of a finished run in ``out`` (as the user named it) trained with ``config``."""
    q = shlex.quote(out)
    lines = [f"run folder: {out}"]
    for name, what in FILES.items():
        path = os.path.join(out, name)
        if name == "checkpoints":
            steps = sorted((int(d) for d in os.listdir(path) if d.isdigit()), reverse=True) \
                if os.path.isdir(path) else []
            if steps:
                lines.append(f"  {name}/{steps[0]}/  {what} (env steps {steps[0]:,}; "
                             f"{len(steps)} kept)")
        elif os.path.exists(path):
            lines.append(f"  {name:<13} {what} ({_size(path)})")
    total = int(config["total_steps"])
    longer = 2 * total
    if min(int(config.get("buffer_size", total)), longer) > min(int(config.get("buffer_size", total)), total):
        # an off-policy replay buffer sized by the budget would grow: a longer run would not continue this one
        resume = (f"python -m train --out {q} --resume", "continue it, should it have been interrupted")
    else:
        resume = (f"python -m train --out {q} --resume --steps {longer}", f"train it further, as a {longer}-step run")
    cmds = [(f"python -m train.render --checkpoint {q} --seed 0", "a GIF of seed 0's greedy episode"),
            (f"python -m train --eval-only {q} --eval-episodes 20", "evaluate the saved policies again"),
            resume]
    if config["scenario"] == "merge-v0":
        cmds.append(("python -m train.experiments --study agents",
                     "hierarchies against flat learners at K = 2, 3, 4: runs, figure, AGENTS.md"))
    elif config["scenario"] not in TRAFFIC_SCENARIOS and int(config.get("agents") or 2) == 2:
        cmds.append((f"python -m train.experiments --only {config['scenario']}",
                     "every algorithm on this scenario: runs, figures, RESULTS.md"))
    width = max(len(c) for c, _ in cmds)
    lines.append("next:")
    lines += [f"  {c:<{width}}  # {why}" for c, why in cmds]
    return "\n".join(lines)
