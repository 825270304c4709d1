"""How many vehicles highway-env's own intersection episodes hold at once (sizes the JAX vehicle pool).

Runs highway-env's ``intersection-v0`` (and the multi-agent task with K agents) with its own random
generator and random actions for the full duration, and records the largest number of vehicles on the
road after any simulation frame. ``envs_jax``'s default pool (``default_num_slots``: K +
initial_vehicle_count + one spawn per step) is an upper bound no default episode can exceed; this
script shows how much room it leaves.

    python -m benchmarks.intersection_pool --episodes 100 --out benchmarks/results/intersection_pool.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def run(k: int, episodes: int, seed0: int) -> dict:
    from highway_env.envs.intersection_env import IntersectionEnv, MultiAgentIntersectionEnv

    from envs_jax.scenarios.intersection_traffic import default_num_slots

    cls = IntersectionEnv if k == 1 else MultiAgentIntersectionEnv
    env = cls(config={"controlled_vehicles": k})
    counts = []
    for e in range(episodes):
        env.reset(seed=seed0 + e)
        rng = np.random.default_rng(seed0 + e)
        most = len(env.road.vehicles)
        step = env.road.step

        def counted(dt, step=step):
            nonlocal most
            step(dt)
            most = max(most, len(env.road.vehicles))

        env.road.step = counted
        done = False
        while not done:
            a = rng.integers(0, 3, size=k)
            _, _, terminated, truncated, _ = env.step(int(a[0]) if k == 1 else tuple(int(u) for u in a))
            most = max(most, len(env.road.vehicles))
            done = terminated or truncated
        counts.append(most)
    cfg = env.config
    bound = default_num_slots(k, cfg["initial_vehicle_count"], cfg["duration"], cfg["policy_frequency"])
    return {"controlled_vehicles": k, "episodes": episodes, "max_vehicles": int(max(counts)),
            "mean_max_vehicles": float(np.mean(counts)), "p99_max_vehicles": float(np.percentile(counts, 99)),
            "default_num_slots": bound}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--agents", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    t0 = time.time()
    rows = []
    for k in args.agents:
        rows.append(run(k, args.episodes, 1000))
        print(json.dumps(rows[-1]), flush=True)
    out = {"task": "intersection-v0 / intersection-multi-agent-v0 (highway-env 1.12.1, own RNG, random actions, "
                   "until terminated or truncated)", "rows": rows, "seconds": round(time.time() - t0, 1)}
    print(json.dumps(out, indent=1))
    if args.out:
        with open(args.out, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
