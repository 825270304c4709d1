"""How envs_jax's step cost grows with the number of vehicles: highway-v0 with 10, 25, 50 and 100 other vehicles.

For each ``vehicles_count`` (highway-env's key: the background vehicles; the controlled one makes V = count + 1
slots) and each number of parallel environments, the same jitted random-action roll-out as
``env_throughput.py`` (auto-reset, compilation apart), and EnvPool's ``highway-v0`` with the same
``vehicles_count`` beside it when envpool is installed. All programs are compiled first, then timed in
``--repeats`` interleaved rounds (every point once per round), so a change of the machine's load touches every
point alike; figures are medians over the rounds. The growth is the least-squares exponent ``b`` of
``seconds per env step ~ V ** b`` over the points (b = 1: linear, 2: quadratic).

    python benchmarks/vehicle_scaling.py                     # writes benchmarks/results/vehicle_scaling.json
    python benchmarks/vehicle_scaling.py --envs 1 --vehicles 10 50
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import jax  # noqa: E402

import baseline_sims  # noqa: E402
import envs_jax  # noqa: E402
from env_throughput import TaskAutoReset, jax_runner, load  # noqa: E402

TASK = "highway-v0"


def exponent(slots, steps_per_s) -> float:
    """Least-squares ``b`` in ``1 / steps_per_s ~ slots ** b``."""
    return float(np.polyfit(np.log(np.asarray(slots, float)), -np.log(np.asarray(steps_per_s, float)), 1)[0])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--vehicles", nargs="+", type=int, default=[10, 25, 50, 100],
                        help="highway-env's vehicles_count (other vehicles; slots V = this + 1)")
    parser.add_argument("--envs", nargs="+", type=int, default=[1, 64], help="numbers of parallel environments")
    parser.add_argument("--env-steps", type=int, default=256,
                        help="environment steps per measurement (T = max(4, this / N))")
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds over all points (median)")
    parser.add_argument("--envpool-envs", type=int, default=2,
                        help="EnvPool environments (synchronous, threads = cores)")
    parser.add_argument("--envpool-seconds", type=float, default=2.0,
                        help="time EnvPool is stepped per point and round")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "vehicle_scaling.json"))
    args = parser.parse_args(argv)
    bad = [v for v in args.vehicles if v < 0]
    if bad:
        raise ValueError(f"--vehicles must be >= 0, got {bad}")

    ep_ids, ep_note = baseline_sims.envpool_tasks()
    with_envpool = TASK in ep_ids
    if not with_envpool:
        print(f"EnvPool skipped: {ep_note}")
    results = {"machine": {"cpus": os.cpu_count(), "jax": jax.__version__, "device": str(jax.devices()[0])},
               "task": TASK, "envpool": ep_note, "rows": []}
    print(f"{TASK}: device {jax.devices()[0]}, {os.cpu_count()} CPUs, load {load():.1f}")
    points = []  # (vehicles_count, slots, num_envs, num_steps, run), run: seconds of one timed call
    for count in args.vehicles:
        env = envs_jax.make(TASK, vehicles_count=count)
        for n in args.envs:
            t = max(4, args.env_steps // n)
            run = jax_runner(env, n, t, TaskAutoReset)
            t0 = time.perf_counter()
            run(jax.random.key(0)).block_until_ready()
            compile_s = time.perf_counter() - t0
            points.append(dict(vehicles_count=count, slots=env.num_slots, num_envs=n, num_steps=t,
                               compile_s=compile_s, run=run, times=[], loads=[]))
            print(f"compiled {count} vehicles, {n} envs: {compile_s:.1f} s (load {load():.1f})")
    envpool_points = [dict(vehicles_count=count, rates=[], loads=[]) for count in args.vehicles] if with_envpool else []
    for r in range(args.repeats):
        for p in points:
            t0 = time.perf_counter()
            p["run"](jax.random.key(r + 1)).block_until_ready()
            p["times"].append(time.perf_counter() - t0)
            p["loads"].append(load())
        for p in envpool_points:
            row = baseline_sims.measure_envpool(TASK, args.envpool_envs, args.envpool_envs, args.envpool_seconds,
                                                1, vehicles_count=p["vehicles_count"])
            p["rates"].append(row["steps_per_s"])
            p["loads"].append(load())
        print(f"round {r + 1}/{args.repeats} done (load {load():.1f})")

    print(f"{'vehicles':>8} {'slots':>5} {'envs':>5} {'steps':>5} {'steps/s':>10} {'compile s':>9} {'load':>5}")
    for p in points:
        med = statistics.median(p["times"])
        row = {k: p[k] for k in ("vehicles_count", "slots", "num_envs", "num_steps")}
        row.update(seconds=med, steps_per_s=p["num_envs"] * p["num_steps"] / med,
                   compile_s=max(p["compile_s"] - med, 0.0), load=statistics.median(p["loads"]),
                   steps_per_s_rounds=[p["num_envs"] * p["num_steps"] / x for x in p["times"]])
        results["rows"].append(row)
        print(f"{row['vehicles_count']:>8} {row['slots']:>5} {row['num_envs']:>5} {row['num_steps']:>5} "
              f"{row['steps_per_s']:>10,.0f} {row['compile_s']:>9.1f} {row['load']:>5.1f}")
    for p in envpool_points:
        row = {"vehicles_count": p["vehicles_count"], "num_envs": args.envpool_envs, "num_threads": os.cpu_count(),
               "steps_per_s": statistics.median(p["rates"]), "steps_per_s_rounds": p["rates"],
               "load": statistics.median(p["loads"])}
        results.setdefault("envpool_rows", []).append(row)
        print(f"{p['vehicles_count']:>8} {p['vehicles_count'] + 1:>5} {'EnvPool':>11} {row['steps_per_s']:>10,.0f} "
              f"{'':>9} {row['load']:>5.1f}")

    series = {f"envs_jax_{n}_envs": [(r["slots"], r["steps_per_s"]) for r in results["rows"] if r["num_envs"] == n]
              for n in args.envs}
    if with_envpool:
        series["envpool"] = [(r["vehicles_count"] + 1, r["steps_per_s"]) for r in results["envpool_rows"]]
    fits, local = {}, {}
    for label, points in series.items():
        if len(points) < 2:
            continue
        fits[label] = exponent(*zip(*points))
        # between neighbouring vehicle counts: where the growth bends
        local[label] = [exponent(*zip(*points[i:i + 2])) for i in range(len(points) - 1)]
    results["exponent"], results["local_exponents"] = fits, local
    for label in fits:
        print(f"cost per env step ~ V ** b, {label}: b = {fits[label]:.2f} "
              f"(between neighbouring counts: {', '.join(f'{b:.2f}' for b in local[label])})")
    with open(args.out, "w") as f:
        json.dump(results, f, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
