"""Training curves of a study (``train.experiments``), one figure per scenario, PNG and PDF (matplotlib, Agg).

Top row: leader, follower and total episode return against training steps. Bottom row: the event curves, crash
rate and the leader's and follower's arrival rate (racetrack: crash rate, off-road rate, distance driven by the
leader and the follower). Each algorithm is one line: episodes are binned by the env step at which they ended
(``end_step`` of ``episodes.csv``), each seed's episodes in a bin are averaged, and the line is the mean over seeds
with a 95% bootstrap band across seeds. The authors' recorded values (last 10% of training, one marker per seed,
docs/results.md) sit at the right edge, clearly labelled with their own training budget. When the runs'
budgets are 4x apart or more (the quick study's MADDPG vs MAPPO-L) the step axis is logarithmic; runs whose envs
stepped fewer than 5 episode limits each (512 parallel envs) are named in red under the title, since their
finished episodes over-represent the short (crashed) ones.

``plot_learner`` draws each agent's Lagrange multiplier and cost estimate against training steps
(``learner.csv``), one line per run. ``python -m train.figures STUDY_DIR`` redraws the figures of a study folder
(with ``<scenario>_learner.png`` where its runs logged a multiplier or cost estimate); ``python -m train.figures
--learner RUN_DIR ... --out FILE`` draws those of any run folders side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

from jaxsmarl import metrics, stats
from jaxsmarl.learner_log import FIELDS as LEARNER_FIELDS
from jaxsmarl.learner_log import LearnerLog
from train.reference_results import AUTHORS, authors_values
from train.study import STUDY

__all__ = ["load_run", "binned_curve", "scenario_panels", "plot_scenario", "plot_learner", "make_figures",
           "ALGO_STYLE"]

RETURN_PANELS = [("leader_return", "leader return"), ("follower_return", "follower return"),
                 ("total_return", "total return")]
EVENT_PANELS = {
    "default": [("crash", "crash rate"), ("leader_arrived", "leader arrival rate"),
                ("follower_arrived", "follower arrival rate")],
    "racetrack": [("crash", "crash rate"), ("offroad", "off-road rate"), ("leader_distance", "leader distance (m)"),
                  ("follower_distance", "follower distance (m)")],
}
ALGO_STYLE = {
    "csq": ("CSQ", "tab:blue"), "sq": ("SQ (Bi-AC: CSQ, d=100)", "tab:orange"),
    "cs-maddpg": ("CS-MADDPG", "tab:blue"), "s-maddpg": ("S-MADDPG (Bi-AC)", "tab:orange"),
    "c-maddpg": ("C-MADDPG", "tab:purple"), "maddpg": ("MADDPG", "tab:brown"),
    "mappo-l": ("MAPPO-L", "tab:green"), "macpo": ("MACPO", "tab:red"),
}


def label(algo: str) -> str:
    return ALGO_STYLE.get(algo, (algo, None))[0]


def authors_label(scenario: str, algo: str) -> str:
    """Legend entry of the authors' markers: one per algorithm, whichever panel drew them (a field recorded for
    fewer seeds, e.g. roundabout SQ's crash rate, must not add a second entry)."""
    ref = AUTHORS[(scenario, algo)]
    steps = ref["steps"]
    budget = f"{steps // 1000}k steps" if steps else "budget unknown"
    n = max(len(authors_values(scenario, algo, f)) for f, _ in RETURN_PANELS)
    return f"{label(algo)}: authors' record, last 10% ({budget}, {n} seeds)"


def load_run(run_dir: str) -> dict | None:
    """``config``, ``summary`` (summary.json) and ``episodes`` (column arrays of episodes.csv) of a run folder;
    None when it holds no episodes yet."""
    csv_path = os.path.join(run_dir, "episodes.csv")
    cfg_path = os.path.join(run_dir, "config.json")
    if not (os.path.exists(csv_path) and os.path.exists(cfg_path)):
        return None
    with open(cfg_path) as f:
        config = json.load(f)
    summary = None
    if os.path.exists(os.path.join(run_dir, "summary.json")):
        with open(os.path.join(run_dir, "summary.json")) as f:
            summary = json.load(f)
    log = metrics.EpisodeLog.read_csv(csv_path, int(config["num_seeds"]))
    cols = {k: np.asarray([r[k] for r in log.rows], np.float64)
            for k in metrics.ID_FIELDS + log.fields}
    learner = LearnerLog.read_csv(os.path.join(run_dir, "learner.csv"))
    return {"dir": run_dir, "config": config, "summary": summary, "episodes": cols, "log": log, "learner": learner}


def per_seed_series(run: dict, field: str) -> list[tuple[np.ndarray, ...]]:
    """Per seed: ``(end_step, value)`` of its episodes in order, plus their weights where the run has them
    (binned records, :mod:`train.records`: each row stands for the episodes of one bin)."""
    ep = run["episodes"]
    out = []
    for s in range(int(run["config"]["num_seeds"])):
        m = ep["seed"] == s
        order = np.argsort(ep["episode"][m], kind="stable")
        item = (ep["end_step"][m][order], ep[field][m][order])
        out.append(item + (ep["weight"][m][order],) if "weight" in ep else item)
    return out


def binned_curve(series: list[tuple[np.ndarray, ...]], total_steps: int, n_bins: int = 20,
                 reps: int = 2000, seed: int = 0):
    """Bin centres ``[B]``, mean over seeds ``[B]`` and its 95% bootstrap band ``[B]``, ``[B]`` across seeds.

    Bin b holds the episodes that ended in ``(b * w, (b + 1) * w]`` env steps, ``w = total_steps / n_bins``; a
    seed contributes the mean of its episodes in the bin (weighted, where a series has a third array of weights;
    no episode: no contribution). NaN where no seed has one.
    """
    edges = np.linspace(0, total_steps, n_bins + 1)
    per_seed = np.full((len(series), n_bins), np.nan)
    for i, item in enumerate(series):
        steps, values = item[0], item[1]
        weights = item[2] if len(item) > 2 else np.ones_like(values)
        b = np.clip(np.searchsorted(edges, steps, side="left") - 1, 0, n_bins - 1)
        for j in range(n_bins):
            sel = (b == j) & (weights > 0)
            if sel.any():
                per_seed[i, j] = np.average(values[sel], weights=weights[sel])
    mean, lo, hi = (np.full(n_bins, np.nan) for _ in range(3))
    for j in range(n_bins):
        col = per_seed[:, j][np.isfinite(per_seed[:, j])]
        if col.size:
            mean[j], lo[j], hi[j] = stats.stratified_bootstrap_ci(col, np.mean, reps=reps, seed=seed)
    return (edges[:-1] + edges[1:]) / 2, mean, lo, hi


def episode_limit(scenario: str) -> int | None:
    """The scenario's episode time limit in decisions (envs_jax default parameters), None if unavailable."""
    try:
        import envs_jax
        from envs_jax.time_limit import episode_step_limit

        env = envs_jax.make(scenario)
        return episode_step_limit(env, env.default_params)
    except Exception:  # a figure must not fail over a caveat
        return None


def short_runs(scenario: str, runs: dict[str, dict], factor: int = 5) -> list[str]:
    """Runs whose envs each stepped fewer than ``factor`` episode limits: among their finished episodes the short
    ones (crashes) are over-represented (e.g. 512 envs x 64 steps on the racetrack, whose episodes last up to 200)."""
    limit = episode_limit(scenario)
    out = []
    for algo, run in runs.items():
        n_envs = int(run["config"].get("num_envs", 1))
        per_env = int(run["config"]["total_steps"]) // n_envs
        if limit and per_env < factor * limit:
            out.append(f"{label(algo)}: {n_envs} envs x {per_env} steps, episodes up to {limit}")
    return out


def scenario_panels(scenario: str) -> list[tuple[str, str]]:
    return RETURN_PANELS + EVENT_PANELS.get(scenario, EVENT_PANELS["default"])


def plot_scenario(scenario: str, runs: dict[str, dict], out_base: str, n_bins: int = 20,
                  formats: tuple[str, ...] = ("png", "pdf")) -> list[str]:
    """Draw one scenario's figure from ``{algo: load_run(...)}``; writes ``out_base.<format>`` for each of
    ``formats``. Runs without episodes (``run["episodes"] is None``) are left out."""
    runs = {a: r for a, r in runs.items() if r.get("episodes") is not None}
    if not runs:
        return []
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = scenario_panels(scenario)
    ncols = max(len(RETURN_PANELS), len(panels) - len(RETURN_PANELS))
    fig, axes = plt.subplots(2, ncols, figsize=(4.2 * ncols, 6.6), squeeze=False)
    positions = [(0, c) for c in range(len(RETURN_PANELS))] + \
                [(1, c) for c in range(len(panels) - len(RETURN_PANELS))]
    for r in range(2):
        for c in range(ncols):
            if (r, c) not in positions:
                axes[r, c].set_visible(False)
    budgets = [int(r["config"]["total_steps"]) for r in runs.values()] or [1]
    x_max = max(budgets)
    # Budgets 4x apart or more (quick study: MADDPG 3,000 steps, MAPPO-L 32,768): a linear axis would squeeze the
    # shorter runs into its first few percent, so the axis is logarithmic, from the first bin of the shortest run.
    log_x = x_max >= 4 * min(budgets)
    x_min = min(budgets) / n_bins / 2
    ref_drawn = False
    for (field, title), (r, c) in zip(panels, positions):
        ax = axes[r, c]
        for k, (algo, run) in enumerate(runs.items()):
            name, color = ALGO_STYLE.get(algo, (algo, None))
            total = int(run["config"]["total_steps"])
            x, mean, lo, hi = binned_curve(per_seed_series(run, field), total, n_bins)
            n = int(run["config"]["num_seeds"])
            line, = ax.plot(x, mean, color=color, label=f"{name} (ours, {n} seeds)")
            ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2, linewidth=0)
            ref = authors_values(scenario, algo, field)
            if ref:
                xr = x_max * ((1.08 + 0.06 * k) if log_x else (1.03 + 0.02 * k))
                ax.scatter([xr] * len(ref), ref, marker="x", s=30, color=line.get_color(), zorder=5,
                           label=authors_label(scenario, algo))
                ref_drawn = True
        ax.set_title(title)
        if log_x:
            ax.set_xscale("log")
            ax.set_xlabel("training env steps per seed (log scale)")
            ax.set_xlim(x_min * 0.8, x_max * (1.08 + 0.06 * len(runs)))
        else:
            ax.set_xlabel("training env steps per seed")
            ax.set_xlim(0, x_max * (1.03 + 0.02 * len(runs)) + x_max * 0.02)
        ax.grid(alpha=0.3)
        if field in ("crash", "offroad", "leader_arrived", "follower_arrived"):
            ax.set_ylim(-0.03, 1.03)
    handles, labels = [], []
    for ax in axes.ravel():
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    note = ("  x: authors' recorded value per seed, drawn at the right edge" if ref_drawn else "")
    fig.suptitle(f"{scenario}: mean over seeds with 95% bootstrap band across seeds{note}", fontsize=11)
    short = short_runs(scenario, runs)
    if short:
        fig.text(0.5, 0.935, "; ".join(short) + ": short (crashed) episodes finish first and are over-represented",
                 ha="center", va="top", fontsize=8, color="tab:red")
    # one legend column per algorithm (ours, then the authors' record below it; legends fill column by column)
    if len(labels) == 2 * len(runs):
        fits = int(fig.get_figwidth() // 4.0)  # legend columns of ~4 inches
        ncol = len(runs) if len(runs) <= fits else -(-len(runs) // 2)
    else:
        ncol = max(1, min(3, len(labels)))
    fig.legend(handles, labels, loc="lower center", ncol=ncol, fontsize=8, frameon=False)
    n_rows_legend = -(-len(labels) // ncol)
    fig.tight_layout(rect=(0, 0.035 * n_rows_legend + 0.02, 1, 0.95))
    os.makedirs(os.path.dirname(os.path.abspath(out_base)), exist_ok=True)
    paths = []
    for ext in formats:
        path = f"{out_base}.{ext}"
        fig.savefig(path, dpi=110)
        paths.append(path)
    plt.close(fig)
    return paths


LEARNER_TITLES = {"lambda": "Lagrange multiplier", "cost_estimate": "cost estimate"}


def plot_learner(runs: dict[str, dict], out_base: str, title: str = "") -> list[str]:
    """Each agent's multiplier and cost estimate against training steps, one line per run of ``{name:
    load_run(...)}`` (mean over seeds, 95% bootstrap band across seeds); writes ``out_base.png``. Returns the
    paths written (none when no run logged either field)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    have = {name: run for name, run in runs.items() if run.get("learner") is not None and run["learner"].rows}
    panels = [(f, i) for f in LEARNER_FIELDS for i in range(max((r["learner"].num_agents() for r in have.values()),
                                                                 default=0))
              if any(r["learner"].series(f, i) for r in have.values())]
    if not panels:
        return []
    agent_name = lambda i: ("leader" if i == 0 else "follower") if len(panels) <= 4 else f"agent {i}"
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.6), squeeze=False)
    for ax, (field, i) in zip(axes[0], panels):
        for name, run in have.items():
            series = run["learner"].series(field, i)
            if not series:
                continue
            steps = sorted(set().union(*(set(x.tolist()) for x, _ in series.values())))
            grid = np.asarray(steps, np.float64)
            ys = np.stack([np.interp(grid, x, y, left=np.nan, right=np.nan) for x, y in series.values()])
            mean, lo, hi = [], [], []
            for col in ys.T:
                col = col[np.isfinite(col)]
                m, a, b = metrics.bootstrap_ci(col.tolist()) if col.size else (np.nan,) * 3
                mean.append(m), lo.append(a), hi.append(b)
            line, = ax.plot(grid, mean, label=f"{name} ({len(series)} seeds)")
            ax.fill_between(grid, lo, hi, color=line.get_color(), alpha=0.2, linewidth=0)
        ax.set_title(f"{agent_name(i)}: {LEARNER_TITLES[field]}")
        ax.set_xlabel("training env steps per seed")
        ax.grid(alpha=0.3)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    for ax in axes[0, 1:]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h), labels.append(lab)
    fig.legend(handles, labels, loc="lower center", ncol=min(3, len(labels)), fontsize=8, frameon=False)
    fig.suptitle(title or "multiplier and cost estimate: mean over seeds, 95% bootstrap band", fontsize=10)
    n_rows = -(-len(labels) // min(3, len(labels)))
    fig.tight_layout(rect=(0, 0.06 * n_rows + 0.02, 1, 0.93))
    os.makedirs(os.path.dirname(os.path.abspath(out_base)), exist_ok=True)
    path = f"{out_base}.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]


def study_runs(study_dir: str) -> dict[str, dict[str, dict]]:
    """``{scenario: {algo: run}}`` of every run folder ``study_dir/runs/<scenario>_<algo>`` with episodes."""
    out: dict[str, dict[str, dict]] = {}
    runs_dir = os.path.join(study_dir, "runs")
    for scenario, algos in STUDY.items():
        for algo in algos:
            run = load_run(os.path.join(runs_dir, f"{scenario}_{algo}"))
            if run is not None:
                out.setdefault(scenario, {})[algo] = run
    return out


def make_figures(study_dir: str, n_bins: int = 20) -> dict[str, list[str]]:
    """Every scenario's figure into ``study_dir/figures/<scenario>_curves.{png,pdf}``."""
    out = {}
    for scenario, runs in study_runs(study_dir).items():
        out[scenario] = plot_scenario(scenario, runs, os.path.join(study_dir, "figures", f"{scenario}_curves"),
                                      n_bins)
        out[scenario] += plot_learner({label(a): r for a, r in runs.items()},
                                      os.path.join(study_dir, "figures", f"{scenario}_learner"),
                                      f"{scenario}: multiplier and cost estimate (mean over seeds, 95% band)")
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m train.figures", description="Redraw a study's training curves.")
    p.add_argument("study_dir", nargs="?", help="folder written by python -m train.experiments")
    p.add_argument("--bins", type=int, default=20, help="bins along the training steps (default 20)")
    p.add_argument("--learner", nargs="+", metavar="RUN_DIR",
                   help="instead: draw the multipliers and cost estimates of these run folders into --out")
    p.add_argument("--out", help="with --learner: output path without extension")
    args = p.parse_args(argv)
    if args.learner:
        runs = {}
        for d in args.learner:
            run = load_run(d)
            if run is None:
                print(f"error: {d} is not a run folder with episodes (config.json, episodes.csv)", file=sys.stderr)
                return 2
            runs[os.path.basename(os.path.normpath(d))] = run
        paths = plot_learner(runs, args.out or "learner")
        if not paths:
            print("error: none of these runs logged a multiplier or cost estimate (learner.csv)", file=sys.stderr)
            return 2
        print(", ".join(paths))
        return 0
    if args.study_dir is None:
        p.error("give a study folder, or --learner RUN_DIR ...")
    if args.bins < 1 or not os.path.isdir(os.path.join(args.study_dir, "runs")):
        print(f"error: {args.study_dir} has no runs/ folder (or --bins < 1)", file=sys.stderr)
        return 2
    for scenario, paths in make_figures(args.study_dir, args.bins).items():
        print(f"{scenario}: {', '.join(paths)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
