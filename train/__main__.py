"""Command line: ``python -m train --scenario merge --algo csq --seeds 8``.

Trains N seeds of one algorithm on one scenario in one compiled program, writes per-episode metrics,
checkpoints and a summary into the run folder, then evaluates the greedy policies. ``--help`` lists everything.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

from train.config import (
    ALGOS,
    COMMON,
    COMMON_HELP,
    SCENARIOS,
    load_config,
    parse_set,
    preset_values,
    read_run_config,
    with_overrides,
)


def _keys_help() -> str:
    """Every configuration key: the common ones, then each group of algorithms sharing a key set."""
    lines = ["common keys:"]
    lines += [f"  {k:<24} {COMMON_HELP[k]} (default {json.dumps(COMMON[k])})" for k in COMMON]
    groups: dict[int, list] = {}
    for name, sp in ALGOS.items():
        groups.setdefault(id(sp.defaults), []).append(sp)
    for specs in groups.values():
        sp = specs[0]
        lines.append(f"keys of {', '.join(s.name for s in specs)}:")
        lines += [f"  {k:<24} {sp.help[k]} (default {json.dumps(sp.defaults[k])})" for k in sp.defaults]
    return "\n".join(lines)


def _presets_help() -> str:
    """What each ``--preset`` sets, per group of algorithms sharing the same values."""
    groups: dict[str, list[str]] = {}
    for name, sp in ALGOS.items():
        for preset, values in sp.presets.items():
            text = " ".join(f"{k}={json.dumps(v)}" for k, v in values.items())
            groups.setdefault(f"{preset}: {text}", []).append(name)
    if not groups:
        return "  (none)"
    return "\n".join(f"  --preset {what.split(':')[0]} for {', '.join(algos)}:{what.split(':', 1)[1]}"
                     for what, algos in groups.items())


def _algos_help() -> str:
    return "; ".join(f"{n} = {sp.summary} [{sp.action}]" for n, sp in ALGOS.items())

EPILOG = """\
examples:
  python -m train                                       # merge, CSQ, 8 seeds, the authors' 20k steps
  python -m train --scenario roundabout --algo sq --seeds 4 --steps 5000
  python -m train --out runs/m --resume                 # continue an interrupted run (bit-identical)
  python -m train --out runs/racetrack_macpo --resume --steps 4194304   # train a finished run further,
                                                        # exactly as a 4194304-step run would have
  python -m train --eval-only runs/m --eval-episodes 20  # greedy evaluation of a saved run
  python -m train --set leader_rule=authors --set infeasible=argmax   # the authors' action rule
  python -m train --scenario racetrack --algo cs-maddpg --preset authors   # every coded option of theirs
  python -m train --scenario highway --agents 3 --hierarchy "0|1,2"   # CSQ, one leader, two followers
  python -m train --scenario highway --agents 3 --algo mappo-l   # the no-hierarchy on-policy baseline
  python -m train --scenario racetrack-v0 --agents 3 --algo cs-maddpg --hierarchy "0|1|2"   # a chain of three
  python -m train --sweep lr=[3e-4,1e-3,3e-3] --seeds 8   # 3 learning rates x 8 seeds in one program
  python -m train --sweep env.collision_reward=[-1,-5] --set env.speed_reward=1   # environment parameters
  python -m train --seeds 8 --coordinator-address 127.0.0.1:12355 --num-processes 2 --process-id 0   # and id 1
                                                        # (several processes and hosts: docs/distributed.md)

configuration: defaults <- train/configs/<scenario>_<algo>.json <- --config FILE <- --preset <- options and --set.
presets (the authors' coded options, docs/algorithms.md):
""" + _presets_help() + """

--set accepts the common keys and those of the chosen algorithm (value in JSON syntax; plain words are taken
as strings):
""" + _keys_help()


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m train", description=__doc__.split("\n\n")[1],
                                formatter_class=argparse.RawDescriptionHelpFormatter, epilog=EPILOG)
    p.add_argument("--scenario", choices=list(SCENARIOS), default=None,
                   help="driving scenario (default merge): merge, roundabout, highway and merge-v0 (highway-env's "
                        "tasks with K controlled vehicles among traffic) and merge-cavs (MARL_CAVs' merge, up to K "
                        "CAVs) have discrete actions, intersection, racetrack and racetrack-v0 (racetrack-v0 with K "
                        "controlled vehicles) continuous ones; the algorithm must match")
    p.add_argument("--algo", choices=list(ALGOS), default=None, help=_algos_help() + " (default csq)")
    p.add_argument("--agents", type=int, default=None, metavar="K",
                   help="controlled agents (default: the scenario's, 2; --scenario highway and merge-v0 take 2..8, "
                        "CSQ up to 4; merge-cavs 3 or 4, the most CAVs of its easy or medium traffic; racetrack-v0 "
                        "2..8, default 3)")
    p.add_argument("--hierarchy", default=None, metavar="LEVELS",
                   help="who decides before whom (CSQ, SQ, S-MADDPG, CS-MADDPG): levels of agent indices, '|' "
                        "between levels and ',' within one, e.g. '0|1|2' (vertical chain, the default), '0,1|2' (two "
                        "leaders), '0,1,2' (no hierarchy, the only one MAPPO-L and MACPO take)")
    p.add_argument("--seeds", type=int, default=None, help="number of seeds trained in parallel (default 8)")
    p.add_argument("--seed", type=int, default=None, help="base random seed (default 0)")
    p.add_argument("--steps", type=int, default=None,
                   help="environment steps per seed (default: the authors' budget, e.g. merge 20000, racetrack 500000)")
    p.add_argument("--num-envs", type=int, default=None, help="parallel environments per seed (default 1)")
    p.add_argument("--out", default=None, help="run folder (default runs/<scenario>_<algo>)")
    p.add_argument("--config", default=None, help="JSON file replacing train/configs/<scenario>_<algo>.json")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override any configuration key (repeatable), e.g. --set lr=3e-4 --set cost_threshold=[2,2]")
    p.add_argument("--sweep", action="append", default=[], metavar="KEY=[V1,V2,...]",
                   help="train every combination of these values (repeatable), each with all the seeds, in one "
                        "compiled program; real-valued keys only (learning rates, thresholds, multiplier rates, "
                        "exploration, loss weights) and environment parameters as env.<field> (e.g. "
                        "env.collision_reward); results per configuration in <out>/configs/")
    p.add_argument("--preset", default=None, metavar="NAME",
                   help="a named set of values applied after the config file and before --set; 'authors' turns on "
                        "every coded option of the authors' implementation (listed below)")
    p.add_argument("--chunk-steps", type=int, default=None,
                   help="environment steps per compiled chunk between host logging (default 1000)")
    p.add_argument("--checkpoint-every", type=int, default=None,
                   help="environment steps between checkpoints, a multiple of --chunk-steps (default 5000)")
    p.add_argument("--resume", action="store_true",
                   help="continue the run in --out from its newest checkpoint (same configuration; with a larger "
                        "--steps, train a finished run further exactly as a longer run would have); on a sweep's "
                        "folder, continue that sweep")
    p.add_argument("--overwrite", action="store_true", help="delete an existing run in --out and start over")
    p.add_argument("--eval-episodes", type=int, default=None,
                   help="greedy evaluation episodes per seed after training (default 10; 0 skips)")
    p.add_argument("--eval-only", metavar="RUN_DIR", default=None,
                   help="only evaluate the newest checkpoint of RUN_DIR greedily and print the result")
    p.add_argument("--print-config", action="store_true", help="print the resolved configuration and exit")
    g = p.add_argument_group("several processes (docs/distributed.md)")
    g.add_argument("--coordinator-address", default=None, metavar="HOST:PORT",
                   help="process 0's address and a free port; with --num-processes and --process-id this process "
                        "is one of several training the seeds together (env: JAX_COORDINATOR_ADDRESS)")
    g.add_argument("--num-processes", type=int, default=None, help="number of processes (env: JAX_NUM_PROCESSES)")
    g.add_argument("--process-id", type=int, default=None,
                   help="this process's index, 0 .. num_processes-1; process 0 writes the run folder's files "
                        "(env: JAX_PROCESS_ID)")
    g.add_argument("--distributed", action="store_true",
                   help="join a multi-process run, letting JAX detect the values not given (SLURM, Open MPI)")
    g.add_argument("--heartbeat-timeout", type=int, default=None, metavar="SECONDS",
                   help="a process silent this long is declared dead and the others stop with an error "
                        "(default 30)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    return p.parse_args(argv)


def build_config(args: argparse.Namespace) -> dict:
    """The validated configuration for ``args`` (raises ValueError before anything is compiled)."""
    overrides = parse_set(args.set)
    for opt, key in (("seeds", "num_seeds"), ("seed", "seed"), ("steps", "total_steps"), ("num_envs", "num_envs"),
                     ("chunk_steps", "chunk_steps"), ("checkpoint_every", "checkpoint_every"),
                     ("eval_episodes", "eval_episodes"), ("agents", "agents"), ("hierarchy", "hierarchy")):
        v = getattr(args, opt)
        if v is not None:
            overrides[key] = v
    if args.resume and args.out:
        from train.sweep_folder import is_sweep_folder, saved_base

        sweep_folder = is_sweep_folder(args.out)
        if sweep_folder or os.path.exists(os.path.join(args.out, "config.json")):
            # continue with the saved configuration (a sweep's: its base); explicit options must agree
            base = saved_base(args.out) if sweep_folder else read_run_config(args.out)
            if args.preset is not None:
                base.update(preset_values(args.algo or base["algo"], args.preset))
            base = with_overrides(base, overrides)
            return load_config(args.scenario or base["scenario"], args.algo or base["algo"], base)
    return load_config(args.scenario, args.algo, overrides, config_file=args.config, preset=args.preset)


def main(argv=None) -> int:
    args = parse_args(argv)
    from train.xla_flags import use_all_cpu_cores

    use_all_cpu_cores()  # seeds are split over the cores (a no-op once JAX has started, e.g. inside tests)
    try:
        from train import distributed

        cluster = distributed.from_options(args.coordinator_address, args.num_processes, args.process_id,
                                           args.distributed, args.heartbeat_timeout)
        if cluster.requested and not args.print_config:
            distributed.initialize(cluster)
        if args.eval_only:
            from train.evaluation import evaluate_checkpoint

            ev = evaluate_checkpoint(args.eval_only, episodes=args.eval_episodes)
            print(json.dumps({"env_steps": ev["env_steps"], **ev["summary"]}, indent=2))
            return 0
        cfg = build_config(args)
        if args.print_config:
            print(json.dumps(cfg, indent=2))
            return 0
        from train.sweep_folder import is_sweep_folder, read_sweep

        resume_sweep = args.resume and args.out is not None and is_sweep_folder(args.out)
        if args.sweep or resume_sweep:
            from train.sweep import parse_sweep, run_sweep, sweep_configs

            out = args.out or os.path.join("runs", f"{cfg['scenario']}_{cfg['algo']}_sweep")
            if args.resume and not resume_sweep:
                read_sweep(out)  # says that the folder holds no sweep
            # --resume alone continues the saved sweep; with --sweep options they must be the saved ones
            sweep = parse_sweep(args.sweep) if args.sweep else read_sweep(out)["sweep"]
            sweep_configs(cfg, sweep)  # refuses keys that cannot be swept before anything is compiled
            res = run_sweep(cfg, sweep, out, resume=args.resume, overwrite=args.overwrite, verbose=not args.quiet)
            if not args.quiet:
                print(f"sweep of {len(res['configs'])} configurations x {cfg['num_seeds']} seeds: {out}/sweep.json, "
                      f"{out}/configs/<configuration>/, {out}/figures/")
            return 0
        out = args.out or os.path.join("runs", f"{cfg['scenario']}_{cfg['algo']}")
        from train.run import run

        res = run(cfg, out, resume=args.resume, overwrite=args.overwrite, verbose=not args.quiet)
        if not args.quiet and res["summary"]["finished"]:
            from train.next_steps import next_steps

            print(next_steps(out, cfg))
    except ValueError as e:  # bad input, a refused run folder, no valid checkpoint
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (RuntimeError, OSError) as e:
        from jaxsmarl.checkpoints import (
            CheckpointWriteError,  # here: importing orbax early would start JAX
        )

        if not isinstance(e, (CheckpointWriteError, OSError)):
            raise
        print(f"error: {e}; the run stopped", file=sys.stderr)  # a write failed (no space, permission denied)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
