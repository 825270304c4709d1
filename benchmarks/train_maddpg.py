"""Training speed of racetrack CS-MADDPG: env steps per second for 1, 8 and 32 seeds, compilation reported apart.

    python benchmarks/train_maddpg.py                          # 5,000 steps per seed, 1 / 8 / 32 seeds
    python benchmarks/train_maddpg.py --steps 20000 --seeds 8 --algo s-maddpg

Each configuration runs the compiled training chunks exactly as ``python -m train`` does (the loop of
``benchmarks/train_csq.py``: ``init`` and one chunk compiled ahead of time and timed as "compile", then every chunk
of the budget, no file I/O). The default budget is a prefix of the authors' 500k steps; after the 512-step warm-up
every env step is one gradient update of all six networks (batch 256), so the rate is representative of the whole
run. ``--profile`` also times the update alone (a scan of updates on a fixed batch, seeds vmapped and split over
the cores as in training) and reports the floating-point work per update, to show where the time goes.
Results go to ``benchmarks/results/train_maddpg.json`` with the machine's load average: on a shared CPU other
processes slow the figures down.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import jax  # noqa: E402

from train.config import load_config  # noqa: E402
from train.parallel import seed_parallel, seed_sharding  # noqa: E402
from train.xla_flags import use_all_cpu_cores  # noqa: E402

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "train_maddpg.json")


def update_flops(agent) -> float:
    """Floating-point operations of one update (one seed), from XLA's cost analysis of the compiled update."""
    st = jax.eval_shape(agent.init, jax.random.PRNGKey(0))
    batch = jax.tree.map(lambda x: jax.ShapeDtypeStruct((256,) + x.shape, x.dtype), agent.transition_example())
    lowered = jax.jit(agent.update).lower(st, batch, jax.random.PRNGKey(0))
    cost = lowered.compile().cost_analysis()
    cost = cost[0] if isinstance(cost, (list, tuple)) else cost
    return float(cost.get("flops", float("nan")))


def profile_update(seeds: int, scenario: str, algo: str, n: int = 300) -> dict:
    """Updates per second alone (fixed random batch of 256, ``n`` updates in one scan per seed)."""
    from train.algos.maddpg import make_agent
    from train.trainer import make_env

    cfg = load_config(scenario, algo, {})
    agent = make_agent(cfg, make_env(scenario)[0])
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    sh = seed_sharding(seeds)
    st = jax.device_put(jax.vmap(agent.init)(keys), sh)
    ex = agent.transition_example()
    batch = jax.tree.map(lambda x: jax.random.uniform(jax.random.PRNGKey(1), (seeds, cfg["batch_size"]) + x.shape)
                         .astype(x.dtype), ex)
    batch = jax.device_put(batch, sh)

    def many(s, b):
        return jax.lax.scan(lambda c, _: (agent.update(c, b, jax.random.PRNGKey(0))[0], None), s, None, length=n)[0]

    f = seed_parallel(many, seeds).lower(st, batch).compile()
    jax.block_until_ready(f(st, batch))
    t = time.perf_counter()
    jax.block_until_ready(f(st, batch))
    dt = time.perf_counter() - t
    flops = update_flops(agent)
    return {"seeds": seeds, "updates_per_s_per_seed": round(n / dt, 1),
            "updates_per_s_all_seeds": round(seeds * n / dt, 1),
            "mflop_per_update": round(flops / 1e6, 1), "gflop_per_s": round(seeds * n * flops / dt / 1e9, 1)}


def main(argv=None) -> int:
    from train_csq import bench

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=5000, help="environment steps per seed (default 5000)")
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 8, 32], help="seed counts to run (default 1 8 32)")
    p.add_argument("--chunk-steps", type=int, default=1000, help="environment steps per compiled chunk")
    p.add_argument("--scenario", default="racetrack")
    p.add_argument("--algo", default="cs-maddpg")
    p.add_argument("--profile", action="store_true", help="also time the update alone and count its FLOPs")
    p.add_argument("--json", default=RESULTS, help="write the results to this JSON file")
    a = p.parse_args(argv)
    use_all_cpu_cores()
    head = (f"jax {jax.__version__} on {jax.devices()[0].platform} ({len(jax.devices())} devices), {os.cpu_count()} "
            f"CPUs; {a.scenario}/{a.algo}, {a.steps} env steps per seed")
    print(head)
    print(f"{'seeds':>5} {'compile s':>9} {'train s':>8} {'steps/s/seed':>12} {'steps/s all':>11} {'load 1m':>12}")
    results = {"setup": head, "runs": [], "update_only": []}
    for s in a.seeds:
        r = bench(s, a.steps, a.chunk_steps, a.scenario, a.algo)
        results["runs"].append(r)
        print(f"{s:>5} {r['compile_s']:>9.1f} {r['train_s']:>8.1f} {r['steps_per_s_per_seed']:>12,.0f} "
              f"{r['steps_per_s_all_seeds']:>11,.0f} {r['load_avg_1m'][0]:>5.1f}->{r['load_avg_1m'][1]:<5.1f}",
              flush=True)
    if a.profile:
        for s in a.seeds:
            r = profile_update(s, a.scenario, a.algo)
            r["load_avg_1m"] = round(os.getloadavg()[0], 2)
            results["update_only"].append(r)
            print(f"update only, {s} seeds: {r['updates_per_s_all_seeds']:,.0f} updates/s over all seeds, "
                  f"{r['mflop_per_update']} MFLOP per update -> {r['gflop_per_s']} GFLOP/s", flush=True)
    os.makedirs(os.path.dirname(a.json), exist_ok=True)
    with open(a.json, "w") as f:
        json.dump(results, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
