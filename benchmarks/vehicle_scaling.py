"""How envs_jax's step cost grows with the number of vehicles: highway-v0 with 10, 25, 50 and 100 other vehicles.

For each ``vehicles_count`` (highway-env's key: the background vehicles; the controlled one makes V = count + 1
slots) and each number of parallel environments, the same jitted random-action roll-out as
``env_throughput.py`` (auto-reset, median of repeats, compilation apart), and EnvPool's ``highway-v0`` with the same
``vehicles_count`` beside it when envpool is installed. The growth is the least-squares exponent ``b`` of
``seconds per env step ~ V ** b`` over the points (b = 1: linear, 2: quadratic).

    python benchmarks/vehicle_scaling.py                     # writes benchmarks/results/vehicle_scaling.json
    python benchmarks/vehicle_scaling.py --envs 1 --vehicles 10 50
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import jax  # noqa: E402

import baseline_sims  # noqa: E402
import envs_jax  # noqa: E402
from env_throughput import TaskAutoReset, load, measure_jax  # noqa: E402

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
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per point (median)")
    parser.add_argument("--envpool-envs", type=int, default=2, help="EnvPool environments (synchronous, threads = cores)")
    parser.add_argument("--envpool-seconds", type=float, default=4.0, help="time EnvPool is stepped per point")
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
    print(f"{'vehicles':>8} {'slots':>5} {'envs':>5} {'steps':>5} {'steps/s':>10} {'compile s':>9} {'load':>5}")
    for count in args.vehicles:
        env = envs_jax.make(TASK, vehicles_count=count)
        for n in args.envs:
            row = measure_jax(env, n, max(4, args.env_steps // n), args.repeats, wrapper=TaskAutoReset)
            row.update(vehicles_count=count, slots=env.num_slots)
            results["rows"].append(row)
            print(f"{count:>8} {env.num_slots:>5} {n:>5} {row['num_steps']:>5} {row['steps_per_s']:>10,.0f} "
                  f"{row['compile_s']:>9.1f} {row['load']:>5.1f}")
        if with_envpool:
            row = baseline_sims.measure_envpool(TASK, args.envpool_envs, args.envpool_envs, args.envpool_seconds,
                                                args.repeats, vehicles_count=count)
            row.update(vehicles_count=count, load=load())
            results.setdefault("envpool_rows", []).append(row)
            print(f"{count:>8} {count + 1:>5} {'EnvPool':>11} {row['steps_per_s']:>10,.0f} {'':>9} {row['load']:>5.1f}")
        with open(args.out, "w") as f:  # after every vehicle count: a run cut short keeps what it measured
            json.dump(results, f, indent=2)

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
