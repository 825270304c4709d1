"""Training speed of merge CSQ: wall time and environment steps per second, compilation reported apart.

    python benchmarks/train_csq.py                      # the authors' 20k steps, for 1, 8 and 32 seeds
    python benchmarks/train_csq.py --steps 2000 --seeds 1 8

Each configuration compiles ``init`` and one training chunk ahead of time (timed as "compile"), then runs every
chunk of the budget exactly as ``python -m train`` does (timed as "train"; no checkpoint or file I/O). Steps are
environment steps (= decisions = gradient updates after the 512-step warm-up); "all seeds" counts every seed's
steps. The machine's load average is printed too: on a shared CPU other processes slow the figures down.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from train.config import load_config  # noqa: E402
from train.programs import compiled_chunks, program  # noqa: E402
from train.trainer import seed_keys  # noqa: E402
from train.xla_flags import use_all_cpu_cores  # noqa: E402


def bench(seeds: int, steps: int, chunk_steps: int, scenario: str, algo: str) -> dict:
    cfg = load_config(scenario, algo, dict(num_seeds=seeds, total_steps=steps, chunk_steps=min(chunk_steps, steps),
                                           checkpoint_every=0, eval_episodes=0))
    prog = program(cfg)  # the programs python -m train runs: seeds split over the CPU cores
    trainer = prog["trainer"]
    keys = seed_keys(cfg)
    t0 = time.perf_counter()
    state = prog["init"](keys)
    jax.block_until_ready(state)
    compiled = compiled_chunks(prog, state)
    chunk, tail = compiled["chunk"], compiled.get("tail")
    compile_s = time.perf_counter() - t0
    load0 = os.getloadavg()[0]
    t1, c1 = time.perf_counter(), time.process_time()
    for c in range(trainer.n_chunks):
        fn = tail if (tail is not None and c == trainer.n_chunks - 1) else chunk
        state, m = fn(state, jnp.int32(c * trainer.chunk_iters))
        jax.block_until_ready(m)
    train_s = time.perf_counter() - t1
    cpu_s = time.process_time() - c1
    crash = float(jnp.sum(m["episode"]["crash"] * m["episode"]["returned"]) / jnp.maximum(
        jnp.sum(m["episode"]["returned"]), 1))
    return {"seeds": seeds, "steps_per_seed": steps, "compile_s": round(compile_s, 2), "train_s": round(train_s, 2),
            "wall_s": round(compile_s + train_s, 2), "steps_per_s_per_seed": round(steps / train_s, 1),
            "steps_per_s_all_seeds": round(seeds * steps / train_s, 1), "cpu_s": round(cpu_s, 1),
            "load_avg_1m": [round(load0, 2), round(os.getloadavg()[0], 2)], "last_chunk_crash_rate": round(crash, 3)}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=20000, help="environment steps per seed (default: the authors' 20000)")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 8, 32], help="seed counts to run (default 1 8 32)")
    p.add_argument("--chunk-steps", type=int, default=2000, help="environment steps per compiled chunk")
    p.add_argument("--scenario", default="merge")
    p.add_argument("--algo", default="csq")
    p.add_argument("--json", default=None, help="also write the results to this JSON file")
    p.add_argument("--one-device", action="store_true", help="do not split seeds over the CPU cores")
    a = p.parse_args(argv)
    if not a.one_device:
        use_all_cpu_cores()
    print(f"jax {jax.__version__} on {jax.devices()[0].platform} ({len(jax.devices())} devices), "
          f"{os.cpu_count()} CPUs; "
          f"{a.scenario}/{a.algo}, {a.steps} env steps per seed")
    print(f"{'seeds':>5} {'compile s':>9} {'train s':>8} {'wall s':>7} {'steps/s/seed':>12} {'steps/s all':>11} "
          f"{'load 1m':>12}")
    results = []
    for s in a.seeds:
        r = bench(s, a.steps, a.chunk_steps, a.scenario, a.algo)
        results.append(r)
        print(f"{s:>5} {r['compile_s']:>9.1f} {r['train_s']:>8.1f} {r['wall_s']:>7.1f} "
              f"{r['steps_per_s_per_seed']:>12,.0f} "
              f"{r['steps_per_s_all_seeds']:>11,.0f} {r['load_avg_1m'][0]:>5.1f}->{r['load_avg_1m'][1]:<5.1f}",
              flush=True)
    if a.json:
        with open(a.json, "w") as f:
            json.dump(results, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
