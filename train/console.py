"""What a run prints: the progress line (rewritten in place on a terminal) and the final report."""

from __future__ import annotations

import sys

from jaxsmarl import metrics

__all__ = ["say", "final_report"]


def say(msg: str, live: bool, end: str = "\n") -> None:
    if live and sys.stdout.isatty():
        sys.stdout.write("\r\033[K" + msg + ("" if end == "\r" else end))
    else:
        sys.stdout.write(msg + "\n")
    sys.stdout.flush()


def final_report(name: str, summary: dict) -> str:
    s, t = summary["summary"], summary["timing"]
    f = lambda k: "{:.2f} [{:.2f}, {:.2f}]".format(*s[k]["last"])
    lines = [f"{name}: {t['env_steps_run']} env steps/seed in {metrics.format_duration(t['train_s'])} "
             f"({t['env_steps_per_s_all_seeds']:,.0f} steps/s over all seeds; compile {t['compile_s']:.1f}s)",
             f"  last 10% of episodes (mean [95% CI] across seeds): return L {f('leader_return')} "
             f"F {f('follower_return')} T {f('total_return')} | crash {f('crash')}"]
    if "eval" in summary:
        e = summary["eval"]
        g = lambda k: "{:.2f} [{:.2f}, {:.2f}]".format(*e[k]["mean_ci"])
        lines.append(f"  greedy evaluation: return L {g('leader_return')} F {g('follower_return')} | "
                     f"crash {g('crash')}")
    return "\n".join(lines)
