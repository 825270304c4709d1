"""The K-agent study: does the Stackelberg structure buy safety or return as the number of agents grows?

```
python -m train.experiments --study agents                   # merge-v0 (K = 2, 3, 4) and merge-cavs (K = 3, 4)
python -m train.experiments --study agents --agents 2 --agents 3   # a subset of K
python -m train.experiments --study agents --report-only     # redraw the figure and AGENTS.md
```

Scenarios: highway-env's ``merge-v0`` with its IDM traffic and K = 2, 3, 4 controlled vehicles, and MARL_CAVs'
merge ``merge-cavs`` at K = 3 (easy traffic, 1-3 CAVs per episode) and K = 4 (medium, 2-4); there K is the most
CAVs an episode can have, and an agent absent from an episode earns 0 reward and 0 cost, so "per agent" below means
per agent slot. Per scenario and K: CSQ with the vertical chain (``0|1|...``), the horizontal split (the first
``ceil(K/2)`` agents lead, the others follow, e.g. ``0,1|2,3``; at K = 2 it is the chain and is not run twice)
and no hierarchy (``0,1,...``, all agents on one level), and the flat MAPPO-L and MACPO, each with the scenario's
shipped configuration (``train/configs/<scenario>_<algo>.json``) and 8 seeds. Study folder (``--out``, default
``runs/agents_study``)::

    runs/<scenario>_K<k>_<method>/   one run folder each (train.run)
    figures/<scenario>_agents.png    the four measures against K, one line per method
    study.json                       what was asked, what each run did, its wall-clock time
    AGENTS.md                        the tables and the comparisons

Every measure is first reduced to one value per seed: the mean over its greedy evaluation episodes (the main
table; exploration off) or over its last 10% of training episodes; across seeds, the inter-quartile mean with a 95%
stratified bootstrap interval (:mod:`jaxsmarl.stats`), as in :mod:`train.report`. Return and cost are per agent
(the episode's sum over agents divided by K), so they compare across K; ``speed`` is the mean speed over the
agent-steps driven (:func:`jaxsmarl.metrics.episode_record`).
"""

from __future__ import annotations

import datetime
import os
import sys

import numpy as np

from train.report import _fmt, compare, interval

__all__ = ["SCENARIOS", "AGENTS", "SCENARIO_AGENTS", "SCENARIO_NOTES", "METHODS", "SEEDS", "hierarchy", "plan",
           "collect", "measure", "render_report", "plot", "write_report"]

SCENARIOS = ("merge-v0", "merge-cavs")
AGENTS = (2, 3, 4)
# the K each scenario takes (merge-cavs: its easy and medium traffic, train/config.py)
SCENARIO_AGENTS = {"merge-v0": (2, 3, 4), "merge-cavs": (3, 4)}
# a sentence under a scenario's heading in AGENTS.md
SCENARIO_NOTES = {
    "merge-v0": "highway-env's merge-v0 with its four IDM vehicles and K controlled vehicles.",
    "merge-cavs": "MARL_CAVs' merge: K = 3 is its easy traffic (1-3 CAVs and 1-3 IDM vehicles per episode), K = 4 "
                  "its medium traffic (2-4 and 2-4). An agent absent from an episode earns 0 reward and 0 cost, so "
                  "return and cost per agent are per agent slot (the episode's sum over the K slots divided by K).",
}
# (method name, algorithm, hierarchy shape): Stackelberg methods first, then their flat counterparts
METHODS = (("csq-chain", "csq", "chain"), ("csq-horizontal", "csq", "horizontal"), ("csq-flat", "csq", "flat"),
           ("mappo-l", "mappo-l", None), ("macpo", "macpo", None))
SEEDS = 8
# (key, column title, digits): the measures of the tables and the figure
MEASURES = (("return", "return per agent", 2), ("crash", "crash rate", 3), ("cost", "cost per agent", 2),
            ("speed", "speed (m/s)", 2))


def hierarchy(shape: str | None, k: int) -> str | None:
    """The ``--hierarchy`` of a method with ``k`` agents (None: the algorithm has no hierarchy)."""
    agents = [str(i) for i in range(k)]
    if shape is None:
        return None
    if shape == "chain":
        return "|".join(agents)
    if shape == "flat":
        return ",".join(agents)
    if shape == "horizontal":
        lead = (k + 1) // 2
        return ",".join(agents[:lead]) + "|" + ",".join(agents[lead:])
    raise ValueError(f"unknown hierarchy shape {shape!r}; choose chain, horizontal or flat")


def plan(scenarios=SCENARIOS, agents=AGENTS, seeds: int | None = None, steps: int | None = None) -> list[dict]:
    """The runs of the study, in order (per scenario, all methods at the smallest K first), as
    :mod:`train.experiments` items with a ``name``; the horizontal split is left out where it equals the chain
    (K = 2), and a scenario runs only the K it takes (``SCENARIO_AGENTS``)."""
    for k in agents:
        if not isinstance(k, int) or not 2 <= k <= 4:
            raise ValueError(f"--agents for the K-agent study must be 2, 3 or 4 (CSQ's joint-action grid is 5^K), "
                             f"got {k!r}")
    out = []
    for scenario in scenarios:
        for k in sorted(set(agents) & set(SCENARIO_AGENTS[scenario])):
            for method, algo, shape in METHODS:
                h = hierarchy(shape, k)
                if shape == "horizontal" and h == hierarchy("chain", k):
                    continue
                ov = {"agents": k, "num_seeds": SEEDS if seeds is None else seeds}
                if h is not None:
                    ov["hierarchy"] = h
                if steps is not None:
                    ov["total_steps"] = steps
                out.append({"name": f"{scenario}_K{k}_{method}", "scenario": scenario, "algo": algo,
                            "agents": k, "method": method, "overrides": ov, "extra": {}})
    return out


def collect(study_dir, items: list[dict] | None = None,
            steps: int | None = None) -> dict[str, dict[int, dict[str, dict]]]:
    """``{scenario: {K: {method: run}}}`` of the finished runs (summary.json says finished) of ``study_dir``, one
    folder or a list of them: a run is taken from the first folder where it has finished (so one report can join,
    say, longer runs of one method with the baselines' runs of another study); ``steps``: only runs trained for
    that many env steps per seed (an equal-sample comparison)."""
    import json

    items = plan() if items is None else items
    dirs = [study_dir] if isinstance(study_dir, (str, os.PathLike)) else list(study_dir)
    out: dict = {}
    for it in items:
        for folder in dirs:
            path = os.path.join(folder, "runs", it["name"], "summary.json")
            if not os.path.exists(path):
                continue
            with open(path) as f:
                summary = json.load(f)
            if summary.get("finished") and (steps is None or summary["config"]["total_steps"] == steps):
                out.setdefault(it["scenario"], {}).setdefault(it["agents"], {})[it["method"]] = summary
                break
    return out


def measure(summary: dict, key: str, k: int, greedy: bool = True) -> list[float]:
    """Per seed: measure ``key`` of a run's summary.json (greedy evaluation or last 10% of training episodes);
    ``return`` and ``cost`` per agent, ``return_<i>`` one agent's return."""

    def per_seed(field):
        if greedy:
            return np.asarray(summary["eval"][field]["per_seed"], np.float64)
        return np.asarray(summary["summary"][field]["last_per_seed"], np.float64)

    if key in ("return", "cost"):
        return list(sum(per_seed(f"{key}_{i}") for i in range(k)) / k)
    return list(per_seed(key))


def _table(runs: dict[int, dict[str, dict]], greedy: bool) -> list[str]:
    head = "| K | method | " + " | ".join(t for _, t, _ in MEASURES) + " |"
    lines = [head, "|" + "---|" * (2 + len(MEASURES))]
    for k in sorted(runs):
        for method, _, _ in METHODS:
            s = runs[k].get(method)
            if s is None:
                continue
            cells = [_fmt(interval(measure(s, key, k, greedy)), d) for key, _, d in MEASURES]
            lines.append(f"| {k} | {method} | " + " | ".join(cells) + " |")
    return lines


def _agents_table(runs: dict[int, dict[str, dict]]) -> list[str]:
    kmax = max(runs)
    lines = ["| K | method | " + " | ".join(f"agent {i}" for i in range(kmax)) + " |",
             "|" + "---|" * (2 + kmax)]
    for k in sorted(runs):
        for method, _, _ in METHODS:
            s = runs[k].get(method)
            if s is None:
                continue
            cells = [_fmt(interval(measure(s, f"return_{i}", k)), 2) if i < k else "" for i in range(kmax)]
            lines.append(f"| {k} | {method} | " + " | ".join(cells) + " |")
    return lines


def comparisons(runs: dict[int, dict[str, dict]]) -> list[tuple[int, str, str, str, int]]:
    """``(K, method, against, sentence, sign)`` for each Stackelberg method against each flat counterpart, on the
    greedy crash rate and return per agent (sign +1: the method's value is higher, intervals apart)."""
    out = []
    for k in sorted(runs):
        for method in ("csq-chain", "csq-horizontal"):
            for other in ("csq-flat", "mappo-l", "macpo"):
                a, b = runs[k].get(method), runs[k].get(other)
                if a is None or b is None:
                    continue
                for key, what in (("crash", "crash rate"), ("return", "return per agent")):
                    text, sign = compare(method, interval(measure(a, key, k)), other, interval(measure(b, key, k)),
                                         f"{what} at K = {k}")
                    out.append((k, method, other, text, sign))
    return out


def render_report(study_dir: str, study: dict | None = None, items: list[dict] | None = None,
                  figures: dict[str, str] | None = None, all_runs: dict | None = None,
                  steps: int | None = None) -> str:
    """AGENTS.md's text for the finished runs ``all_runs`` (:func:`collect`'s result, collected with ``steps``;
    default: those of ``study_dir``); figure links relative to ``study_dir``."""
    all_runs = collect(study_dir, items, steps) if all_runs is None else all_runs
    if study and study.get("command"):
        origin = f"Generated by `{study['command']}`."
    else:
        now = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
        origin = f"Generated by `python -m train.experiments --study agents` on {now}."
    lines = ["# The K-agent study: hierarchies against flat learners as K grows", "", origin,
             "Per run: IQM across seeds with 95% stratified bootstrap intervals; per seed the mean over its greedy "
             "evaluation episodes (tables 1 and 2) or its last 10% of training episodes (table 3). Return and cost "
             "per agent: the episode's sum over agents divided by K. Methods: CSQ with the vertical chain "
             "(`0|1|..`), the horizontal split (first ceil(K/2) agents lead) and no hierarchy (one level), "
             "MAPPO-L, MACPO.", ""]
    done = {(sc, k, m) for sc, by_k in all_runs.items() for k, r in by_k.items() for m in r}
    planned = plan() if items is None else items
    missing = [it["name"] for it in planned if (it["scenario"], it["agents"], it["method"]) not in done]
    if missing and steps is not None:
        lines += [f"No finished run of {steps:,} env steps per seed (left out of every table and figure): "
                  f"{', '.join(missing)}.", ""]
    elif missing:
        lines += [f"Not finished yet (left out of every table and figure): {', '.join(missing)}.", ""]
    if not all_runs:
        return "\n".join(lines + ["No run has finished yet.", ""])
    for scenario, runs in all_runs.items():
        budgets = sorted({(s["config"]["algo"], s["config"]["num_seeds"], s["config"]["total_steps"])
                          for r in runs.values() for s in r.values()})
        lines += [f"## {scenario}", "", SCENARIO_NOTES.get(scenario, ""), "",
                  "Budgets (algorithm: seeds x env steps per seed): "
                  + "; ".join(f"{a}: {n} x {t:,}" for a, n, t in budgets) + ".", ""]
        fig = (figures or {}).get(scenario)
        if fig:
            lines += [f"![{scenario}: measures against K]({os.path.relpath(fig, study_dir)})", ""]
        lines += ["Greedy evaluation:", ""] + _table(runs, True) + [""]
        lines += ["Return of each agent (greedy evaluation):", ""] + _agents_table(runs) + [""]
        lines += ["Last 10% of training episodes (exploration on):", ""] + _table(runs, False) + [""]
        lines += ["Stackelberg against flat (greedy evaluation; a difference is claimed only where the 95% "
                  "intervals do not overlap):", ""]
        lines += [f"- {text}" for _, _, _, text, _ in comparisons(runs)] + [""]
    return "\n".join(lines)


def plot(runs: dict[int, dict[str, dict]], out_base: str, title: str = "",
         formats: tuple[str, ...] = ("png",)) -> list[str]:
    """The four measures (greedy evaluation) against K, one line per method with its 95% interval as error bars."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(MEASURES), figsize=(4.0 * len(MEASURES), 3.4), squeeze=False)
    ks = sorted(runs)
    for j, (method, _, _) in enumerate(METHODS):
        have = [k for k in ks if method in runs[k]]
        if not have:
            continue
        for ax, (key, name, _) in zip(axes[0], MEASURES):
            cis = np.asarray([interval(measure(runs[k][method], key, k)) for k in have])
            x = np.asarray(have, float) + 0.06 * (j - (len(METHODS) - 1) / 2)
            ax.errorbar(x, cis[:, 0], yerr=[cis[:, 0] - cis[:, 1], cis[:, 2] - cis[:, 0]], marker="o", capsize=3,
                        label=method)
            ax.set_title(name)
            ax.set_xticks(ks)
            ax.set_xlabel("controlled agents K")
    axes[0][0].legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    paths = []
    for fmt in formats:
        path = f"{out_base}.{fmt}"
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        fig.savefig(path, dpi=110)
        paths.append(path)
    plt.close(fig)
    return paths


def write_report(study_dir, study: dict | None = None, items: list[dict] | None = None,
                 out_dir: str | None = None, steps: int | None = None) -> str:
    """Draw the figures into ``out_dir/figures`` and write ``out_dir/AGENTS.md`` (default ``out_dir``: the study
    folder) from the finished runs of ``study_dir`` (one folder or a list; ``steps`` as :func:`collect`); returns its
    path."""
    if out_dir is None:
        if not isinstance(study_dir, (str, os.PathLike)):
            raise ValueError("write_report: out_dir is required when the runs come from several folders")
        out_dir = study_dir
    all_runs = collect(study_dir, items, steps)  # read once, for the figures and the text
    figs = {}
    for scenario, runs in all_runs.items():
        paths = plot(runs, os.path.join(out_dir, "figures", f"{scenario}_agents"),
                     title=f"{scenario}: greedy evaluation, IQM and 95% interval across seeds")
        figs[scenario] = paths[0]
    text = render_report(out_dir, study, items, figs, all_runs, steps)
    out = os.path.join(out_dir, "AGENTS.md")
    with open(out + ".tmp", "w") as f:
        f.write(text)
    os.replace(out + ".tmp", out)
    return out


def main(argv=None) -> int:
    """``python -m train.agents_study --from DIR [--from DIR2 ...] --out DOCS``: AGENTS.md and its figure from
    committed records (``DIR/runs/<name>/summary.json``; a run is taken from the first folder that has it), without
    training; ``--scenario`` and ``--agents`` narrow the report to part of the study, ``--steps`` to the runs of one
    budget."""
    import argparse

    p = argparse.ArgumentParser(prog="python -m train.agents_study", description=main.__doc__.split(":")[0])
    p.add_argument("--from", dest="src", action="append", required=True,
                   help="folder holding runs/<scenario>_K<k>_<method>/ (repeatable: the first folder with a run wins)")
    p.add_argument("--out", required=True, help="folder for AGENTS.md and figures/")
    p.add_argument("--scenario", action="append", choices=SCENARIOS, help="only this scenario (repeatable)")
    p.add_argument("--agents", action="append", type=int, help="only this K (repeatable)")
    p.add_argument("--steps", type=int, help="only runs trained for this many env steps per seed")
    args = p.parse_args(argv)
    for src in args.src:
        if not os.path.isdir(os.path.join(src, "runs")):
            print(f"error: {src} has no runs/ folder", file=sys.stderr)
            return 2
    try:
        items = plan(scenarios=tuple(args.scenario or SCENARIOS), agents=tuple(args.agents or AGENTS))
        if args.steps is not None and args.steps <= 0:
            raise ValueError(f"--steps must be a positive number of env steps per seed, got {args.steps}")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    cmd = ("python -m train.agents_study " + " ".join(f"--from {s}" for s in args.src) + f" --out {args.out}"
           + "".join(f" --scenario {s}" for s in args.scenario or ())
           + "".join(f" --agents {k}" for k in args.agents or ())
           + (f" --steps {args.steps}" if args.steps is not None else ""))
    print(write_report(args.src, {"command": cmd}, items=items, out_dir=args.out, steps=args.steps))
    return 0


if __name__ == "__main__":
    sys.exit(main())
