"""The paper's experiments in one command: every scenario with its algorithms, N seeds, figures and RESULTS.md.

```
python -m train.experiments                      # full study: the authors' budgets, 10 seeds, runs/experiments/
python -m train.experiments --quick              # small budgets (table QUICK below), runs/experiments_quick/
python -m train.experiments --only merge --only racetrack/cs-maddpg --seeds 4
python -m train.experiments --report-only        # redraw figures and RESULTS.md from the finished runs
python -m train.experiments --study agents       # the K-agent study (train/agents_study.py): AGENTS.md
```

Study folder (``--out``)::

    runs/<scenario>_<algo>/   one run folder each (train.run: config.json, episodes.csv, summary.json, eval.csv,
                              checkpoints/)
    figures/                  <scenario>_curves.png/.pdf (train.figures), <scenario>_<algo>.gif (train.render)
    study.json                what was asked, what each run did, and the wall-clock time spent on it
    jax_cache/                JAX's persistent compilation cache (command line only; safe to delete)
    RESULTS.md                tables, figures, GIFs and the honesty section (train.report)

Resumable: a run whose summary.json says ``"finished": true`` is not redone; an interrupted one resumes from its
newest checkpoint (bit-identical to an uninterrupted run); one without a checkpoint starts over. A finished run
trained with a different configuration (e.g. --quick results in a full study's folder) is kept and reported, not
overwritten, unless ``--overwrite``. Algorithms that are not registered in :mod:`train.config` yet are skipped
with a message.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

from train.config import RESUME_FREE, defaults_for, load_config, parse_set, read_run_config
from train.study import STUDY

__all__ = ["STUDY", "QUICK", "DEFAULT_SEEDS", "plan", "parse_only", "run_study", "main"]

DEFAULT_SEEDS = 10

# --quick budgets per (scenario, algo): overrides of the run configuration. Target: the whole study (12 runs, each
# with its compilations, a greedy evaluation and a GIF) in under 15 minutes on an idle 2-core CPU. Every run has 4
# seeds (an even count: seeds are split over both cores) and a budget that is a whole number of chunks (a partial
# last chunk compiles a second program); the measured time is in docs/performance.md. Compilation costs more than
# training at these budgets; a re-run finds its programs in DIR/jax_cache. Learning
# shows in merge (CSQ crash rate 0.75 -> 0.1) and roundabout (total return 20 -> 55-60); MADDPG barely starts in
# 2000 steps; MAPPO-L/MACPO get 4 updates of 512 envs x 16 steps.
QUICK: dict[tuple[str, str], dict] = {
    ("merge", "csq"): {"total_steps": 6000, "num_seeds": 4},
    ("merge", "sq"): {"total_steps": 6000, "num_seeds": 4},
    ("roundabout", "csq"): {"total_steps": 3000, "num_seeds": 4},
    ("roundabout", "sq"): {"total_steps": 3000, "num_seeds": 4},
    ("intersection", "cs-maddpg"): {"total_steps": 2000, "num_seeds": 4},
    ("intersection", "s-maddpg"): {"total_steps": 2000, "num_seeds": 4},
    ("intersection", "mappo-l"): {"total_steps": 32768, "num_seeds": 4},  # 4 updates of 512 envs x 16 steps
    ("intersection", "macpo"): {"total_steps": 32768, "num_seeds": 4},
    ("racetrack", "cs-maddpg"): {"total_steps": 2000, "num_seeds": 4},
    ("racetrack", "s-maddpg"): {"total_steps": 2000, "num_seeds": 4},
    ("racetrack", "mappo-l"): {"total_steps": 32768, "num_seeds": 4},
    ("racetrack", "macpo"): {"total_steps": 32768, "num_seeds": 4},
}
QUICK_EVAL_EPISODES = 10


def parse_only(items) -> list[tuple[str, str]]:
    """``["merge", "racetrack/cs-maddpg", "a,b"]`` -> the selected (scenario, algo) pairs, in study order."""
    if not items:
        return [(s, a) for s, algos in STUDY.items() for a in algos]
    chosen = set()
    for item in items:
        for part in str(item).split(","):
            part = part.strip()
            if not part:
                continue
            scenario, _, algo = part.partition("/")
            if scenario not in STUDY:
                raise ValueError(f"--only {part!r}: unknown scenario {scenario!r}; choose one of "
                                 f"{', '.join(STUDY)} (optionally /algorithm)")
            if algo and algo not in STUDY[scenario]:
                raise ValueError(f"--only {part!r}: the study runs {scenario} with {', '.join(STUDY[scenario])}, "
                                 f"not {algo!r}")
            chosen.update([(scenario, algo)] if algo else [(scenario, a) for a in STUDY[scenario]])
    return [(s, a) for s, algos in STUDY.items() for a in algos if (s, a) in chosen]


def plan(only=None, quick: bool = False, seeds: int | None = None, steps: int | None = None,
         overrides: dict | None = None, budgets: dict | None = None) -> list[dict]:
    """The runs of a study: ``{"scenario", "algo", "overrides"}`` each, budgets applied in this order: default
    seeds, the --quick table (or ``budgets``, a replacement table for tests), ``seeds`` / ``steps``, then
    ``overrides`` (applied to the runs whose algorithm has the key)."""
    if seeds is not None and (not isinstance(seeds, int) or seeds < 1):
        raise ValueError(f"--seeds must be a positive integer, got {seeds!r}")
    if steps is not None and (not isinstance(steps, int) or steps < 1):
        raise ValueError(f"--steps must be a positive integer, got {steps!r}")
    table = budgets if budgets is not None else (QUICK if quick else {})
    out = []
    for scenario, algo in parse_only(only):
        ov: dict = {"num_seeds": DEFAULT_SEEDS}
        if quick:
            ov["eval_episodes"] = QUICK_EVAL_EPISODES
        ov.update(table.get((scenario, algo), {}))
        if seeds is not None:
            ov["num_seeds"] = seeds
        if steps is not None:
            ov["total_steps"] = steps
        out.append({"scenario": scenario, "algo": algo, "overrides": ov, "extra": dict(overrides or {})})
    return out


def _resolve(item: dict) -> tuple[dict | None, str]:
    """The validated config of a planned run, or ``(None, reason)`` when its algorithm is not registered."""
    scenario, algo = item["scenario"], item["algo"]
    try:
        valid = defaults_for(algo)
    except ValueError as e:
        if "unknown algorithm" in str(e):
            return None, f"algorithm '{algo}' is not registered in train.config yet"
        raise
    ov = dict(item["overrides"])
    ov.update({k: v for k, v in item["extra"].items() if k in valid})
    try:
        return load_config(scenario, algo, ov), ""
    except ValueError as e:
        if "unknown algorithm" in str(e):
            return None, f"algorithm '{algo}' is not registered in train.config yet"
        raise


def _read_json(path: str):
    try:
        with open(path) as f:
            return json.load(f)
    except (OSError, json.JSONDecodeError):
        return None


def _saved_config(run_dir: str) -> dict | None:
    """The run folder's configuration with later-added keys at their defaults (``train.config.read_run_config``);
    None when there is no readable one."""
    try:
        return read_run_config(run_dir)
    except (OSError, ValueError):
        return None


def _same(saved: dict | None, config: dict) -> bool:
    if saved is None:
        return False
    return all(saved.get(k) == v for k, v in config.items() if k not in RESUME_FREE)


def _has_checkpoint(run_dir: str) -> bool:
    ckpt = os.path.join(run_dir, "checkpoints")
    if not os.path.isdir(ckpt):
        return False
    from jaxsmarl.checkpoints import Checkpointer

    with Checkpointer(ckpt) as c:
        return c.latest_step() is not None


def run_one(item: dict, study_dir: str, overwrite: bool = False, gifs: bool = True, verbose: bool = True,
            max_chunks: int | None = None) -> dict:
    """Train (or resume, or keep) one run of the study and render its GIF. Returns its status record."""
    import train.run

    scenario, algo = item["scenario"], item["algo"]
    name = item.get("name") or f"{scenario}_{algo}"
    config, reason = _resolve(item)
    if config is None:
        _say(f"{name}: skipped ({reason})", verbose)
        return {"status": "skipped", "reason": reason}
    run_dir = os.path.join(study_dir, "runs", name)
    summary = _read_json(os.path.join(run_dir, "summary.json"))
    saved = _saved_config(run_dir)
    t0 = time.perf_counter()
    status = {"config": config}
    if summary and summary.get("finished") and not overwrite:
        if _same(saved, config):
            _say(f"{name}: finished earlier, kept", verbose)
            status["status"] = "kept"
        else:
            diff = {k: (saved.get(k), v) for k, v in config.items()
                    if k not in RESUME_FREE and saved.get(k) != v}
            msg = (f"finished earlier with a different configuration {diff}; kept as it is (pass --overwrite to "
                   "retrain it, or choose another --out)")
            _say(f"{name}: {msg}", verbose)
            status.update(status="kept (different config)", reason=msg)
    else:
        resume = (not overwrite) and _same(saved, config) and _has_checkpoint(run_dir)
        _say(f"{name}: {'resuming' if resume else 'training'} ({config['num_seeds']} seeds x "
             f"{config['total_steps']} steps)", verbose)
        res = train.run.run(config, run_dir, resume=resume, overwrite=not resume, verbose=verbose,
                             max_chunks=max_chunks)
        status["status"] = ("resumed" if resume else "trained") + ("" if res["summary"]["finished"] else
                                                                   " (interrupted)")
    status["train_wall_s"] = time.perf_counter() - t0
    final = _read_json(os.path.join(run_dir, "summary.json")) or {}
    if gifs and final.get("finished"):
        t1 = time.perf_counter()
        status["gif"] = _render(run_dir, os.path.join(study_dir, "figures", f"{name}.gif"), verbose)
        status["gif_s"] = time.perf_counter() - t1
    return status


def _render(run_dir: str, gif: str, verbose: bool) -> str | None:
    """Seed 0's greedy episode, unless the GIF is newer than the run's summary."""
    from train import render

    summary = os.path.join(run_dir, "summary.json")
    if os.path.exists(gif) and os.path.getmtime(gif) >= os.path.getmtime(summary):
        return gif
    try:
        res = render.render_checkpoint(run_dir, gif, seed=0)
    except Exception as e:  # a figure must never lose a finished study
        _say(f"  GIF of {run_dir} failed: {type(e).__name__}: {e}", verbose)
        return None
    _say(f"  wrote {', '.join(res['paths'])} ({res['frames']} frames)", verbose)
    return gif


def _say(msg: str, verbose: bool) -> None:
    if verbose:
        print(msg, flush=True)


def run_study(out: str, only=None, quick: bool = False, seeds: int | None = None, steps: int | None = None,
              overrides: dict | None = None, budgets: dict | None = None, overwrite: bool = False,
              gifs: bool = True, report_only: bool = False, verbose: bool = True, study_name: str = "paper",
              agents=None) -> dict:
    """Run (or resume) the selected runs, then draw the figures and write RESULTS.md (``study_name="agents"``:
    the K-agent study of :mod:`train.agents_study` for the K in ``agents``, and AGENTS.md). Returns study.json's
    dict."""
    from train import agents_study, figures, report

    if study_name == "agents":
        items = agents_study.plan(agents=agents or agents_study.AGENTS, seeds=seeds, steps=steps)
        for item in items:
            item["extra"] = dict(overrides or {})
    else:
        items = plan(only, quick, seeds, steps, overrides, budgets)
    study_dir = os.path.abspath(out)
    os.makedirs(os.path.join(study_dir, "runs"), exist_ok=True)
    path = os.path.join(study_dir, "study.json")
    study = _read_json(path) or {"runs": {}}
    custom = budgets is not None or seeds is not None or steps is not None or bool(overrides)
    study.update(quick=quick, budgets="custom" if custom else ("quick" if quick else "default"),
                 only=[item.get("name") or f"{item['scenario']}/{item['algo']}" for item in items])
    t0 = time.perf_counter()
    if not report_only:
        for item in items:
            key = item.get("name") or f"{item['scenario']}_{item['algo']}"
            status = run_one(item, study_dir, overwrite, gifs and study_name != "agents", verbose)
            status["wall_s"] = _carried_wall(study["runs"].get(key, {}), status["status"]) + \
                status.pop("train_wall_s", 0.0)
            status.pop("config", None)
            study["runs"][key] = status
            _write_json(path, study)
            _release_compiled_programs()
    if study_name == "agents":
        report_path = agents_study.write_report(study_dir, study, items)
        study["last_invocation_s"] = time.perf_counter() - t0
        _write_json(path, study)
        _say(f"wrote {report_path} ({study['last_invocation_s']:.0f} s)", verbose)
        return study
    t1 = time.perf_counter()
    paths = figures.make_figures(study_dir)
    study["figures_s"] = time.perf_counter() - t1
    _say(f"figures: {', '.join(p for v in paths.values() for p in v if p.endswith('.png')) or 'none'} "
         f"({study['figures_s']:.0f} s)", verbose)
    report_path = report.write_report(study_dir, study)
    study["last_invocation_s"] = time.perf_counter() - t0
    _write_json(path, study)
    _say(f"wrote {report_path} ({study['last_invocation_s']:.0f} s)", verbose)
    return study


def _carried_wall(prev: dict, status: str) -> float:
    """The wall-clock time of earlier invocations that still counts for a run: all of it when the run was kept or
    resumed, none when it was (re)trained from scratch (e.g. ``--overwrite``)."""
    return float(prev.get("wall_s", 0.0)) if status.startswith(("kept", "resumed")) else 0.0


def _write_json(path: str, obj) -> None:
    from jaxsmarl.metrics import write_json

    write_json(path, obj)


def _release_compiled_programs() -> None:
    """Drop the finished run's compiled programs: each XLA:CPU executable keeps a few memory mappings, and a long
    study in one process would otherwise approach the kernel's mapping limit (``vm.max_map_count``), past which
    compilation crashes. The persistent compilation cache makes a later identical program cheap again."""
    import gc

    import jax

    jax.clear_caches()
    gc.collect()


def enable_compile_cache(path: str) -> None:
    """JAX's persistent compilation cache in ``path``: identical programs compile once per study (e.g. CSQ's and
    SQ's init) and a re-run or resumed study skips almost all compilation."""
    import jax

    try:
        jax.config.update("jax_compilation_cache_dir", os.path.abspath(path))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    except Exception as e:  # an optional speed-up: never fail a study over it
        print(f"note: no persistent compilation cache ({type(e).__name__}: {e})", file=sys.stderr)


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="python -m train.experiments", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=(
                                    "study: " + "; ".join(f"{s}: {', '.join(a)}" for s, a in STUDY.items())))
    p.add_argument("--study", choices=("paper", "agents"), default="paper",
                   help="paper: the paper's scenarios and algorithms (RESULTS.md); agents: the K-agent study on "
                        "merge-v0 and merge-cavs, CSQ with three hierarchies against MAPPO-L and MACPO (AGENTS.md)")
    p.add_argument("--agents", type=int, action="append", default=None, metavar="K",
                   help="--study agents: the numbers of agents to run (repeatable; default 2, 3 and 4)")
    p.add_argument("--quick", action="store_true",
                   help="small budgets (the QUICK table in train/experiments.py): the whole study in minutes")
    p.add_argument("--only", action="append", default=[], metavar="SCENARIO[/ALGO]",
                   help="run only these (repeatable, or comma-separated), e.g. --only merge --only racetrack/macpo")
    p.add_argument("--seeds", type=int, default=None, help=f"seeds per run (default {DEFAULT_SEEDS}; --quick: "
                                                           "the QUICK table)")
    p.add_argument("--steps", type=int, default=None,
                   help="env steps per seed for every run (default: the authors' budgets; --quick: the QUICK table)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="configuration override for every run whose algorithm has KEY (value in JSON syntax)")
    p.add_argument("--out", default=None, help="study folder (default runs/experiments, or runs/experiments_quick)")
    p.add_argument("--overwrite", action="store_true", help="retrain the selected runs from scratch")
    p.add_argument("--no-gifs", action="store_true", help="do not render a GIF per run")
    p.add_argument("--report-only", action="store_true", help="train nothing: redraw figures and RESULTS.md")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    default_out = {"agents": "agents_study"}.get(args.study, "experiments_quick" if args.quick else "experiments")
    out = args.out or os.path.join("runs", default_out)
    try:
        overrides = parse_set(args.set)
        if args.study == "agents":
            from train import agents_study

            if args.only or args.quick:
                raise ValueError("--study agents runs its own table (train/agents_study.py): --only and --quick do "
                                 "not apply; choose the K with --agents and the budget with --steps / --seeds")
            items = agents_study.plan(agents=args.agents or agents_study.AGENTS, seeds=args.seeds,
                                      steps=args.steps)
            for item in items:
                item["extra"] = overrides
        elif args.agents:
            raise ValueError("--agents applies to --study agents only")
        else:
            items = plan(args.only, args.quick, args.seeds, args.steps, overrides)
        known = set()
        for item in items:  # validate every registered run's configuration before anything is trained
            config, _ = _resolve(item)
            known.update(config or ())
        unused = sorted(k for k in overrides if k not in known)
        if unused:
            raise ValueError(f"--set {', '.join(unused)}: no selected (registered) algorithm has this key; "
                             "see python -m train --help for the keys")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    import train.xla_flags

    train.xla_flags.use_all_cpu_cores()
    enable_compile_cache(os.path.join(out, "jax_cache"))
    run_study(out, args.only, args.quick, args.seeds, args.steps, overrides, overwrite=args.overwrite,
              gifs=not args.no_gifs, report_only=args.report_only, verbose=not args.quiet, study_name=args.study,
              agents=args.agents)
    return 0


if __name__ == "__main__":
    sys.exit(main())
