"""A/B timing of copies of the ``envs_jax`` package, side by side in one process.

On a shared machine wall-clock figures drift with the other processes; this script
runs single-threaded XLA, interleaves the variants round by round and reports the
*minimum* CPU time (``time.process_time``) per environment step (one decision of both
agents, with auto-reset and random actions, as ``env_throughput.py``), which is the
least disturbed estimate. Variants are package copies with renamed imports:

    python benchmarks/ab_variants.py --snapshot base         # copy the working tree's envs_jax
    ... edit envs_jax ...
    python benchmarks/ab_variants.py --snapshot new
    python benchmarks/ab_variants.py base new --scenarios merge roundabout
    python benchmarks/ab_variants.py base new --check        # same random rollouts? (512 envs)
    python benchmarks/ab_variants.py base new --scenarios highway-v0 merge-v0 --envs 64   # traffic tasks too

``--snapshot NAME`` copies ``envs_jax`` to ``/tmp/variants/ev_NAME`` (``--dir`` to change).
The name ``work`` times the working tree's ``envs_jax`` itself.
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import shutil
import sys
import time

# Only "--" flags: XLA stops reading XLA_FLAGS at the first word that is not one (a former
# "intra_op_parallelism_threads=1" here silently dropped every flag after it).
os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false").strip()
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def snapshot(name: str, directory: str) -> str:
    """Copy ``envs_jax`` to ``directory/ev_<name>`` with every import renamed."""
    pkg = f"ev_{name}"
    dst = os.path.join(directory, pkg)
    shutil.rmtree(dst, ignore_errors=True)
    shutil.copytree(os.path.join(ROOT, "envs_jax"), dst, ignore=shutil.ignore_patterns("__pycache__"))
    for base, _, files in os.walk(dst):
        for f in files:
            if f.endswith(".py"):
                path = os.path.join(base, f)
                with open(path) as fh:
                    text = fh.read()
                with open(path, "w") as fh:
                    fh.write(re.sub(r"\benvs_jax\b", pkg, text))
    return dst


def auto_reset(pkg, name: str):
    """The auto-reset wrapper env_throughput.py uses for ``name``."""
    from env_throughput import TaskAutoReset

    return TaskAutoReset if name in pkg.available_tasks() else pkg.AutoResetWrapper


def runner(pkg, name: str, num_envs: int, num_steps: int):
    """benchmarks/env_throughput.py's jitted roll-out, built from package ``pkg`` (a variant of envs_jax)."""
    from env_throughput import jax_runner

    wrappers = importlib.import_module(pkg.__name__ + ".wrappers")
    return jax_runner(pkg.make(name), num_envs, num_steps, auto_reset(pkg, name), wrappers.random_actions)


def trajectories(pkg, name: str, num_envs: int, num_steps: int):
    """Per-step observations, rewards, costs, done flags and vehicle state of a random rollout."""
    import jax

    env = pkg.make(name)
    wrapped = auto_reset(pkg, name)(env)
    params = env.default_params
    policy = importlib.import_module(pkg.__name__ + ".wrappers").random_actions(env)

    def run(key):
        obs, state = jax.vmap(wrapped.reset, in_axes=(0, None))(jax.random.split(key, num_envs), params)

        def body(carry, k):
            obs, state = carry
            k_act, k_step = jax.random.split(k)
            action = jax.vmap(policy)(jax.random.split(k_act, num_envs), obs)
            obs, state, reward, cost, done, _ = jax.vmap(wrapped.step, in_axes=(0, 0, 0, None))(
                jax.random.split(k_step, num_envs), state, action, params)
            e = state if name in pkg.available_tasks() else state.env_state
            return (obs, state), dict(obs=obs, reward=reward, cost=cost, done=done, x=e.x, y=e.y, heading=e.heading,
                                      speed=e.speed, lane=e.lane, target_lane=e.target_lane, crashed=e.crashed,
                                      impact=e.impact)

        return jax.lax.scan(body, (obs, state), jax.random.split(key, num_steps))[1]

    return jax.device_get(jax.jit(run)(jax.random.key(0)))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("variants", nargs="*", help="variant names (ev_NAME under --dir; 'work' = envs_jax)")
    parser.add_argument("--snapshot", help="copy the working tree's envs_jax as this variant and exit")
    parser.add_argument("--dir", default="/tmp/variants")
    parser.add_argument("--scenarios", nargs="+", default=["merge", "roundabout", "intersection", "racetrack"])
    parser.add_argument("--envs", type=int, default=2048)
    parser.add_argument("--steps", type=int, default=20, help="policy steps per timed run")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--x64", action="store_true")
    parser.add_argument("--check", action="store_true",
                        help="compare the variants' random rollouts (512 envs, 60 steps) instead of timing")
    args = parser.parse_args(argv)
    if args.snapshot:
        print(snapshot(args.snapshot, args.dir))
        return
    import jax

    if args.x64:
        jax.config.update("jax_enable_x64", True)
    sys.path[:0] = [args.dir, ROOT]  # ev_* copies, and the working tree's envs_jax for 'work'
    pkgs = {v: importlib.import_module("envs_jax" if v == "work" else f"ev_{v}") for v in args.variants}
    if args.check:
        import numpy as np

        for name in args.scenarios:
            outs = {v: trajectories(pkg, name, 512, 60) for v, pkg in pkgs.items()}
            ref = outs[args.variants[0]]
            for v, out in outs.items():
                diff = {k: float(np.max(np.abs(np.asarray(out[k], float) - np.asarray(ref[k], float)))) for k in ref}
                bad = {k: d for k, d in diff.items() if d > 0}
                print(f"{name:>12} {v}: {'identical' if not bad else 'max |difference| ' + str(bad)}", flush=True)
        return
    for name in args.scenarios:
        fns = {}
        for v, pkg in pkgs.items():
            fn = runner(pkg, name, args.envs, args.steps)
            t0 = time.perf_counter()
            fn(jax.random.key(0)).block_until_ready()
            print(f"  {name} {v}: compiled+first run {time.perf_counter() - t0:.1f} s", flush=True)
            fns[v] = fn
        best = {v: float("inf") for v in pkgs}
        for r in range(args.rounds):
            for v, fn in fns.items():
                t0 = time.process_time()
                fn(jax.random.key(r + 1)).block_until_ready()
                best[v] = min(best[v], (time.process_time() - t0) / (args.envs * args.steps))
        base = best[args.variants[0]]
        line = "  ".join(f"{v} {best[v] * 1e6:7.2f} us ({base / best[v]:.2f}x)" for v in pkgs)
        print(f"{name:>12}: min CPU time per env-step: {line}", flush=True)


if __name__ == "__main__":
    main()
