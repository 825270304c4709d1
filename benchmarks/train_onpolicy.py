"""Training speed of MAPPO-L and MACPO: environment steps per second during training, compilation apart.

    python benchmarks/train_onpolicy.py    # both algorithms, intersection and racetrack, 1 and 8 seeds
    python benchmarks/train_onpolicy.py --algos macpo --scenarios racetrack --seeds 1 --cycles 2

Uses each scenario's configuration (``train/configs/<scenario>_<algo>.json``: num_envs x rollout_length samples per
update); ``--num-envs`` overrides it. Compiles one chunk of ``--cycles`` rollout+update cycles ahead of time, runs it
once to warm up and then ``--repeats`` times (median wall and process CPU time). "all seeds" counts every
seed's steps. The programs and XLA flags are those of ``python -m train`` (:func:`train.programs.program`,
:func:`train.xla_flags.use_all_cpu_cores`). Writes ``benchmarks/results/train_onpolicy.json`` with the machine's load
average: on a shared CPU the wall-clock figures are low.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from train.config import load_config  # noqa: E402
from train.programs import compiled_chunks, program  # noqa: E402
from train.trainer import seed_keys  # noqa: E402
from train.xla_flags import use_all_cpu_cores  # noqa: E402


def bench(scenario: str, algo: str, seeds: int, cycles: int, repeats: int, num_envs: int | None) -> dict:
    over = dict(num_seeds=seeds, checkpoint_every=0, eval_episodes=0)
    if num_envs:
        over["num_envs"] = num_envs
    base = load_config(scenario, algo, over)
    cycle = base["num_envs"] * base["rollout_length"]
    over.update(total_steps=cycle * cycles, chunk_steps=cycle * cycles)
    cfg = load_config(scenario, algo, over)
    prog = program(cfg)  # the programs python -m train runs
    keys = seed_keys(cfg)
    t0 = time.perf_counter()
    state = prog["init"](keys)
    chunk = compiled_chunks(prog, state)["chunk"]
    compile_s = time.perf_counter() - t0
    state, m = chunk(state, jnp.int32(0))
    jax.block_until_ready(m)
    times, cpu = [], []
    for _ in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        state, m = chunk(state, jnp.int32(0))
        jax.block_until_ready(m)
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    dt, cpu_s = statistics.median(times), statistics.median(cpu)
    steps = cycle * cycles
    return {"scenario": scenario, "algo": algo, "seeds": seeds, "num_envs": cfg["num_envs"],
            "rollout_length": cfg["rollout_length"], "num_minibatches": cfg["num_minibatches"],
            "steps_per_seed": steps, "compile_s": round(compile_s, 2), "chunk_s_median": round(dt, 3),
            "steps_per_s_per_seed": round(steps / dt, 1), "steps_per_s_all_seeds": round(seeds * steps / dt, 1),
            # CPU time of this process (all its threads): on a shared machine the wall-clock rate mostly measures
            # the other processes; steps per CPU-second x cores is what an idle machine would give at best.
            "cpu_s_median": round(cpu_s, 3), "steps_per_cpu_s_all_seeds": round(seeds * steps / cpu_s, 1),
            "load_avg_1min": os.getloadavg()[0]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--algos", nargs="+", default=["mappo-l", "macpo"])
    p.add_argument("--scenarios", nargs="+", default=["intersection", "racetrack"])
    p.add_argument("--seeds", nargs="+", type=int, default=[1, 8])
    p.add_argument("--cycles", type=int, default=2, help="rollout+update cycles per timed chunk")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--num-envs", type=int, default=None)
    p.add_argument("--out", default=os.path.join(os.path.dirname(os.path.abspath(__file__)), "results",
                                                 "train_onpolicy.json"))
    a = p.parse_args(argv)
    use_all_cpu_cores()
    rows = []
    for scen in a.scenarios:
        for algo in a.algos:
            for s in a.seeds:
                r = bench(scen, algo, s, a.cycles, a.repeats, a.num_envs)
                rows.append(r)
                print(json.dumps(r), flush=True)
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        json.dump({"jax": jax.__version__, "cpu_count": os.cpu_count(), "date": time.strftime("%Y-%m-%d %H:%M"),
                   "xla_flags": os.environ.get("XLA_FLAGS", ""), "results": rows}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
