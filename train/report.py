"""RESULTS.md of a study (``train.experiments``): tables, figures, GIFs, an honesty section generated from the
numbers, and the known paper-vs-code differences.

Every number of a run is first reduced to one value per seed: the mean over the last ceil(10%) of that seed's
training episodes (the window of the authors' records, docs/results.md, and of summary.json), or the mean over
its greedy evaluation episodes. Across seeds we report the inter-quartile mean (IQM) with a 95% stratified bootstrap
interval
(:mod:`jaxsmarl.stats`). Comparisons say "higher" / "lower" only when the two intervals do not overlap.

``python -m train.report STUDY_DIR`` rewrites RESULTS.md from the run folders;
``python -m train.report --from benchmarks/results/training --out docs/results`` writes RESULTS.md and the PNG
curves from the committed training records (:mod:`train.records`), keeping the GIFs already in ``OUT/figures``.
"""

from __future__ import annotations

import datetime
import json
import os
import sys

import numpy as np

from jaxsmarl import metrics, stats
from train import figures, records
from train.figures import label, short_runs, study_runs
from train.reference_results import AUTHORS, CODE_DIFFERENCES, PAPER_CLAIMS, authors_summary
from train.study import STUDY

__all__ = ["final_per_seed", "eval_per_seed", "interval", "compare", "write_report", "render_report"]

EVENT_FIELDS = {"crash", "offroad", "leader_arrived", "follower_arrived"}


def final_per_seed(run: dict, field: str, frac: float = 0.1) -> list[float]:
    """Per seed: the mean of ``field`` over its last ceil(frac * n) training episodes (``cost`` = leader_cost +
    follower_cost)."""
    final = run.get("final")  # committed records: summary.json's per-seed means over the same last-10% window
    if final is not None and frac == 0.1:
        if field == "cost":
            return [a + b for a, b in zip(final["leader_cost"], final["follower_cost"])]
        return list(final[field])
    log = run["log"]
    if field == "cost":
        per_seed = [a + b for a, b in zip(log.per_seed("leader_cost"), log.per_seed("follower_cost"))]
    else:
        per_seed = log.per_seed(field)
    return metrics.window_means(per_seed, frac, last=True)


def eval_per_seed(run: dict, field: str) -> list[float] | None:
    """Per seed: mean over its greedy evaluation episodes (summary.json "eval"), None without an evaluation."""
    ev = (run.get("summary") or {}).get("eval")
    if not ev:
        return None
    if field == "cost":
        return [a + b for a, b in zip(ev["leader_cost"]["per_seed"], ev["follower_cost"]["per_seed"])]
    return ev.get(field, {}).get("per_seed")


def interval(values) -> tuple[float, float, float]:
    """IQM and its 95% stratified bootstrap interval across seeds."""
    return stats.iqm_ci([np.nan if v is None else v for v in values])


def _fmt(ci, digits: int = 2) -> str:
    p, lo, hi = ci
    if not np.isfinite(p):
        return "n/a"
    if lo == hi == p:
        return f"{p:.{digits}f}"
    return f"{p:.{digits}f} [{lo:.{digits}f}, {hi:.{digits}f}]"


def _digits(field: str) -> int:
    return 3 if field in EVENT_FIELDS else (0 if field.endswith("distance") else 1)


def compare(name_a: str, ci_a, name_b: str, ci_b, what: str) -> tuple[str, int]:
    """A sentence comparing two IQM intervals and the sign: +1 a higher, -1 a lower, 0 overlapping."""
    a, b = _fmt(ci_a, 3), _fmt(ci_b, 3)
    if not (np.isfinite(ci_a[0]) and np.isfinite(ci_b[0])):
        return f"{what}: cannot compare ({name_a} {a}, {name_b} {b}).", 0
    if ci_a[2] < ci_b[1]:
        return f"{name_a}'s {what} is lower than {name_b}'s ({a} vs {b}; the 95% intervals do not overlap).", -1
    if ci_b[2] < ci_a[1]:
        return f"{name_a}'s {what} is higher than {name_b}'s ({a} vs {b}; the 95% intervals do not overlap).", 1
    return (f"{name_a} and {name_b} cannot be told apart on {what}: the 95% intervals overlap ({a} vs {b}); "
            "the data neither support nor refute a difference.", 0)


def _authors_cell(scenario: str, algo: str, field: str, digits: int) -> str:
    s = authors_summary(scenario, algo, field)
    if s is None:
        return "not recorded"
    m, sd, n = s
    return f"{m:.{digits}f} ± {sd:.{digits}f} (n={n})" if n > 1 else f"{m:.{digits}f} (n=1)"


def _budget(run: dict) -> str:
    c = run["config"]
    return f"{c['num_seeds']} x {int(c['total_steps']):,}"


def _timing(run: dict, study: dict, key: str) -> str:
    """``wall W (train T, compile C, other O) + GIF G``: other = initialisation (its compilation too), greedy
    evaluation (compiled), checkpoints and files; W is this study's time on the run, all invocations together."""
    t = (run.get("summary") or {}).get("timing") or {}
    st = (study or {}).get("runs", {}).get(key) or {}
    wall, gif = st.get("wall_s"), st.get("gif_s")
    train = f"train {metrics.format_duration(t.get('train_s', 0))}, compile {t.get('compile_s', 0):.0f}s" if t else ""
    if wall and t and t.get("segments", 1) <= 1:
        other = wall - t.get("train_s", 0) - t.get("compile_s", 0)
        text = f"wall {metrics.format_duration(wall)} ({train}, other {other:.0f}s)"
    elif wall:
        text = f"wall {metrics.format_duration(wall)}" + (f" ({train})" if train else "")
    else:
        text = train or "n/a"
    return text + (f" + GIF {gif:.0f}s" if gif else "")


def _scenario_section(scenario: str, runs: dict[str, dict], study: dict, study_dir: str) -> list[str]:
    lines = [f"## {scenario}", "", f"Paper: {PAPER_CLAIMS.get(scenario, '')}", ""]
    if scenario == "racetrack":
        event_cols = [("crash", "crash rate"), ("offroad", "off-road rate"), ("leader_distance", "distance L (m)"),
                      ("follower_distance", "distance F (m)")]
    else:
        event_cols = [("crash", "crash rate"), ("leader_arrived", "arrival L"), ("follower_arrived", "arrival F")]
    cols = [("leader_return", "return L"), ("follower_return", "return F"), ("total_return", "return total"),
            ("cost", "episode cost (L+F)")] + event_cols
    lines += ["Training, last 10% of each seed's episodes; IQM [95% stratified bootstrap CI] across seeds:", "",
              "| algorithm | seeds x steps | " + " | ".join(c[1] for c in cols) + " |",
              "|---|---|" + "---|" * len(cols)]
    for algo, run in runs.items():
        cells = [_fmt(interval(final_per_seed(run, f)), _digits(f)) for f, _ in cols]
        unfinished = "" if (run.get("summary") or {}).get("finished") else " (unfinished)"
        lines.append(f"| {label(algo)}{unfinished} | {_budget(run)} | " + " | ".join(cells) + " |")
    lines += ["", "Greedy evaluation of the final policies (IQM over seeds of the per-seed mean), the authors' "
              "recorded training values (last 10%, mean ± std over their seeds) and the "
              "run's time:", "",
              "| algorithm | greedy: return total | greedy: crash rate | greedy: seeds with a crash | "
              "authors: return total | authors: crash rate | authors' run | time |",
              "|---|---|---|---|---|---|---|---|"]
    for algo, run in runs.items():
        ev_ret, ev_crash = eval_per_seed(run, "total_return"), eval_per_seed(run, "crash")
        g_ret = _fmt(interval(ev_ret), 1) if ev_ret else "n/a"
        g_crash = _fmt(interval(ev_crash), 3) if ev_crash else "n/a"
        g_seeds = f"{sum(1 for v in ev_crash if v and v > 0)} of {len(ev_crash)}" if ev_crash else "n/a"
        ref = AUTHORS.get((scenario, algo))
        ref_run = (ref["run"] + (f"; {ref['note']}" if ref.get("note") else "")) if ref else "none"
        lines.append(f"| {label(algo)} | {g_ret} | {g_crash} | {g_seeds} | "
                     f"{_authors_cell(scenario, algo, 'total_return', 2)} | "
                     f"{_authors_cell(scenario, algo, 'crash', 3)} | {ref_run} | "
                     f"{_timing(run, study, f'{scenario}_{algo}')} |")
    missing = [a for a in STUDY[scenario] if a not in runs]
    if missing:
        reasons = []
        for a in missing:
            st = ((study or {}).get("runs", {}).get(f"{scenario}_{a}") or {})
            reasons.append(f"{label(a)} ({st.get('reason') or 'not run in this study'})")
        lines += ["", "Not in this study: " + "; ".join(reasons) + "."]
    no_curve = [label(a) for a, r in runs.items() if "episodes" in r and r["episodes"] is None]
    if no_curve:
        lines += ["", f"No training curve for {', '.join(no_curve)}: the record holds no episodes."]
    fig = os.path.join("figures", f"{scenario}_curves.png")
    if os.path.exists(os.path.join(study_dir, fig)):
        lines += ["", f"![{scenario} training curves]({fig})"]
        if os.path.exists(os.path.join(study_dir, "figures", f"{scenario}_curves.pdf")):
            lines[-1] += "  "
            lines.append(f"(PDF: [figures/{scenario}_curves.pdf](figures/{scenario}_curves.pdf))")
    gif_info = (study or {}).get("gifs")  # records mode: {name: how its policy was trained}
    algos = list(runs) if gif_info is None else [a for a in runs if f"{scenario}_{a}" in gif_info]
    gifs = [(a, os.path.join("figures", f"{scenario}_{a}.gif")) for a in algos]
    gifs = [(a, g) for a, g in gifs if os.path.exists(os.path.join(study_dir, g))]
    if gifs:
        head = ("Greedy episode of seed 0 (green: leader, blue: follower, red: crashed):" if gif_info is None else
                "Greedy episode of a policy trained for the picture, not of the recorded runs above (green: leader, "
                "blue: follower, red: crashed):")
        lines += ["", head, "", "| " + " | ".join(label(a) for a, _ in gifs) + " |", "|" + "---|" * len(gifs),
                  "| " + " | ".join(f"![{scenario} {a}]({g})" for a, g in gifs) + " |"]
        if gif_info is not None:
            lines += [""] + [f"- {label(a)}: {gif_info[f'{scenario}_{a}']}" for a, _ in gifs]
    if gif_info is not None:
        absent = [a for a in runs if not any(a == g for g, _ in gifs)]
        reasons = (study or {}).get("no_gif", {})
        if absent:
            lines += ["", "No GIF for " + "; ".join(
                f"{label(a)} ({reasons.get(f'{scenario}_{a}', 'no trained policy at hand')})" for a in absent) + "."]
    return lines + [""]


def _short_budget(scenario: str, run: dict) -> str:
    """A caveat when ``run`` trained for less than half the authors' budget of the same run (else "")."""
    steps = AUTHORS.get((scenario, run["config"]["algo"]), {}).get("steps")
    ours = int(run["config"]["total_steps"])
    if not steps or ours >= 0.5 * steps:
        return ""
    return (f" Caveat: trained for {ours:,} steps per seed, {100 * ours / steps:.0f}% of the authors' {steps:,}; the "
            "paper's claims are about trained policies, so this verdict says little about them.")


def _honesty(all_runs: dict[str, dict[str, dict]]) -> list[str]:
    out = ["## Honesty: where our numbers agree with the paper and where they do not", ""]
    crash = lambda run: interval(final_per_seed(run, "crash"))
    total = lambda run: interval(final_per_seed(run, "total_return"))
    for scenario in ("merge", "roundabout"):
        runs = all_runs.get(scenario, {})
        if "csq" in runs and "sq" in runs:
            s, sign = compare("CSQ", crash(runs["csq"]), "SQ", crash(runs["sq"]), f"{scenario} crash rate")
            verdict = {-1: "agrees with the paper (CSQ safer)", 1: "contradicts the paper (SQ safer)",
                       0: "does not confirm the paper's claim that CSQ is safer"}[sign]
            out.append(f"- **{scenario}, is CSQ safer than SQ?** {s} "
                       f"This {verdict}.{_short_budget(scenario, runs['csq'])}")
            c = final_per_seed(runs["csq"], "crash")
            zero = sum(1 for v in c if v == 0)
            out.append(f"  - The paper calls CSQ {'100% safe after convergence' if scenario == 'merge' else 'safer'}"
                       f": {zero} of {len(c)} CSQ seeds had no crash in their last 10% of training episodes.")
            s, sign = compare("CSQ", total(runs["csq"]), "SQ", total(runs["sq"]), f"{scenario} total return")
            out.append(f"  - Reward: {s}")
        elif runs:
            out.append(f"- **{scenario}:** CSQ vs SQ not compared (both runs are needed).")
    for scenario in ("intersection", "racetrack"):
        runs = all_runs.get(scenario, {})
        if "cs-maddpg" not in runs:
            if runs:
                out.append(f"- **{scenario}:** no CS-MADDPG run, no comparison.")
            continue
        for base in ("macpo", "mappo-l", "s-maddpg"):
            if base not in runs:
                out.append(f"- **{scenario}, CS-MADDPG vs {label(base)}:** not compared ({label(base)} not run).")
                continue
            s1, sign_r = compare("CS-MADDPG", total(runs["cs-maddpg"]), label(base), total(runs[base]),
                                 f"{scenario} total return")
            s2, sign_c = compare("CS-MADDPG", crash(runs["cs-maddpg"]), label(base), crash(runs[base]),
                                 f"{scenario} crash rate")
            beats = sign_r > 0 and sign_c <= 0
            verdict = ("CS-MADDPG beats it, as the paper says" if beats else
                       "the paper's claim that CS-MADDPG beats it is not confirmed by these runs")
            censored = short_runs(scenario, {base: runs[base]})
            censored = (f" {label(base)}'s training statistics over-represent short (crashed) episodes "
                        f"({censored[0].split(': ', 1)[1]}; see the caution below)." if censored else "")
            out.append(f"- **{scenario}, does CS-MADDPG beat {label(base)}?** {s1} {s2} Verdict: {verdict}."
                       f"{_short_budget(scenario, runs['cs-maddpg'])}{censored}")
        if scenario == "racetrack":
            d = lambda run: interval([a + b for a, b in zip(final_per_seed(run, "leader_distance"),
                                                             final_per_seed(run, "follower_distance"))])
            for base in ("macpo", "mappo-l"):
                if base in runs:
                    s, _ = compare("CS-MADDPG", d(runs["cs-maddpg"]), label(base), d(runs[base]),
                                   "distance driven (leader + follower, m)")
                    out.append(f"  - {s}")
    # Against the authors' recorded values
    out += ["", "Against the authors' recorded runs (their last-10% total return, mean over seeds, inside or "
            "outside our 95% interval):", ""]
    for scenario, runs in all_runs.items():
        for algo, run in runs.items():
            ref = authors_summary(scenario, algo, "total_return")
            if ref is None:
                continue
            ci = total(run)
            steps = AUTHORS[(scenario, algo)]["steps"]
            ours = int(run["config"]["total_steps"])
            where = "inside" if ci[1] <= ref[0] <= ci[2] else ("above" if ref[0] > ci[2] else "below")
            budget = (f"our budget {ours:,} steps vs the authors' {steps:,}" if steps else
                      f"our budget {ours:,} steps; the authors' is unknown")
            caveat = " (not comparable: much shorter training)" if steps and ours < 0.5 * steps else ""
            out.append(f"- {scenario} {label(algo)}: authors {ref[0]:.1f} is {where} our {_fmt(ci, 1)}; "
                       f"{budget}{caveat}.")
    censored = [f"{scenario} {item}" for scenario, runs in all_runs.items() for item in short_runs(scenario, runs)]
    if censored:
        out += ["", "Caution: in these runs each parallel env stepped fewer than 5 times the episode limit, so "
                    "episodes that end early (crashes) are over-represented among the finished ones, in the curves' "
                    "first bins and in the last-10% statistics alike: " + "; ".join(censored) + "."]
    seeds = sorted({int(r["config"]["num_seeds"]) for runs in all_runs.values() for r in runs.values()})
    if seeds and min(seeds) < 5:
        n = min(seeds)
        kept = n - 2 * int(0.25 * n)
        what = ("the plain mean of the seeds" if kept == n else
                "the mean of the middle two seeds, i.e. their median" if n == 4 else
                f"the mean of the middle {kept} seeds")
        out += ["", f"Caution: some runs have only {n} seed{'s' if n != 1 else ''}. Their IQM is {what}, and a "
                    "percentile bootstrap over so few seeds gives intervals that are too narrow: read \"the 95% "
                    "intervals do not overlap\" as weak evidence."]
    return out + [""]


def _differences(all_runs: dict[str, dict[str, dict]]) -> list[str]:
    out = ["## Known differences between the paper and the authors' code, and what we follow", ""]
    configs = [r["config"] for runs in all_runs.values() for r in runs.values()]
    for key, paper_value, text in CODE_DIFFERENCES:
        if key is None:
            out.append(f"- {text}")
            continue
        used = sorted({json.dumps(c[key]) for c in configs if key in c})
        if not used:
            continue
        side = "the paper" if used == [json.dumps(paper_value)] else "mixed / the authors' code"
        out.append(f"- {text} Our runs: `{key}` = {', '.join(used)} ({side}).")
    return out + ["", "Details: [docs/algorithms.md](../algorithms.md) and [docs/scenarios.md](../scenarios.md) in the "
                      "repository.", ""]


def render_report(study_dir: str, study: dict | None = None, all_runs: dict | None = None) -> str:
    """RESULTS.md's text for the run folders of ``study_dir`` (or for ``all_runs``, e.g. committed records)."""
    all_runs = study_runs(study_dir) if all_runs is None else all_runs
    quick = bool((study or {}).get("quick"))
    budgets = (study or {}).get("budgets", "quick" if quick else "default")
    kind = {"quick": "quick budgets, far shorter than the authors': a smoke test, not a reproduction",
            "custom": "budgets set on the command line; compare them with the authors' below",
            "default": "the authors' budgets"}.get(budgets, budgets)
    if study and study.get("command"):  # committed records: no date, so that a regeneration changes nothing
        origin = f"Generated by `{study['command']}` ({kind})."
    else:
        now = datetime.datetime.now().strftime("%Y-%m-%d %H:%M")
        origin = f"Generated by `python -m train.experiments{' --quick' if quick else ''}` on {now} ({kind})."
    lines = ["# Results: the paper's experiments, reproduced", "", origin,
             "Per run: IQM across seeds with 95% stratified bootstrap intervals (jaxsmarl.stats); per seed: the mean "
             "over its last 10% of training episodes. The authors' numbers are their shipped records "
             "(3 seeds). Figures: mean over seeds with a 95% bootstrap band.", ""]
    if study and study.get("preamble"):
        lines += list(study["preamble"]) + [""]
    if not all_runs:
        lines += ["No run has produced episodes yet.", ""]
    for scenario, runs in all_runs.items():
        lines += _scenario_section(scenario, runs, study or {}, study_dir)
    lines += _honesty(all_runs)
    lines += _differences(all_runs)
    return "\n".join(lines)


def write_report(study_dir: str, study: dict | None = None) -> str:
    if study is None:
        path = os.path.join(study_dir, "study.json")
        if os.path.exists(path):
            with open(path) as f:
                study = json.load(f)
    text = render_report(study_dir, study)
    out = os.path.join(study_dir, "RESULTS.md")
    with open(out + ".tmp", "w") as f:
        f.write(text)
    os.replace(out + ".tmp", out)
    return out


def _atomic_write(path: str, text: str) -> None:
    with open(path + ".tmp", "w") as f:
        f.write(text)
    os.replace(path + ".tmp", path)


RECORDS_COMMAND = "python -m train.report --from benchmarks/results/training --out docs/results"


def write_records_report(records_dir: str, out: str, table: dict | None = None, n_bins: int = 20) -> dict:
    """RESULTS.md and ``figures/<scenario>_curves.png`` in ``out`` from committed training records
    (:mod:`train.records`). GIFs are not rendered (records hold no checkpoints): those listed in
    ``out/figures/gifs.json`` (``{"gifs": {name: how it was trained}, "no_gif": {name: why not}}``) are embedded.
    Returns ``{"report": path, "figures": [paths]}``."""
    all_runs = records.load_records(records_dir, table)
    fig_dir = os.path.join(out, "figures")
    os.makedirs(fig_dir, exist_ok=True)
    paths = []
    for scenario, runs in all_runs.items():
        paths += figures.plot_scenario(scenario, runs, os.path.join(fig_dir, f"{scenario}_curves"), n_bins,
                                       formats=("png",))
    gif_path = os.path.join(fig_dir, "gifs.json")
    gif_meta = {}
    if os.path.exists(gif_path):
        with open(gif_path) as f:
            gif_meta = json.load(f)
    missing = records.missing(records_dir, table)
    study = {"budgets": "committed training records; budgets per row", "command": RECORDS_COMMAND,
             "runs": {k: {"reason": v} for k, v in missing.items()},
             "gifs": gif_meta.get("gifs", {}), "no_gif": gif_meta.get("no_gif", {}),
             "preamble": [f"Source: the run records committed in `{os.path.relpath(records_dir)}` (one folder per "
                          "row: config, summary with per-seed last-10% means and the greedy evaluation, and binned "
                          "episode means for the curves); which folder stands for which row is "
                          "`train.records.RECORDS`. Other runs there (other budgets, the authors' coded options) "
                          "are discussed in [docs/results.md](../results.md)."]
                         + ([f"Not recorded: {', '.join(sorted(missing))}."] if missing else [])}
    path = os.path.join(out, "RESULTS.md")
    _atomic_write(path, render_report(out, study, all_runs))
    return {"report": path, "figures": paths}


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m train.report", description="Rewrite a study's RESULTS.md, or "
                                "write RESULTS.md and the curves from committed training records.")
    p.add_argument("study_dir", nargs="?", help="folder written by python -m train.experiments (with runs/)")
    p.add_argument("--from", dest="records", metavar="RECORDS_DIR",
                   help="committed record folders, e.g. benchmarks/results/training (needs --out)")
    p.add_argument("--out", help="with --from: the folder for RESULTS.md and figures/, e.g. docs/results")
    args = p.parse_args(argv)
    if args.records:
        if args.study_dir or not args.out:
            print("error: --from RECORDS_DIR takes --out OUT_DIR and no STUDY_DIR", file=sys.stderr)
            return 2
        if not os.path.isdir(args.records):
            print(f"error: --from {args.records}: no such folder", file=sys.stderr)
            return 2
        res = write_records_report(args.records, args.out)
        print("\n".join([res["report"]] + res["figures"]))
        return 0
    if not args.study_dir or not os.path.isdir(os.path.join(args.study_dir, "runs")):
        print("usage: python -m train.report STUDY_DIR | --from RECORDS_DIR --out OUT_DIR\nerror: STUDY_DIR must be "
              "a folder written by python -m train.experiments (with runs/)", file=sys.stderr)
        return 2
    print(write_report(args.study_dir))
    return 0


if __name__ == "__main__":
    sys.exit(main())
