"""Benchmark: hierarchies of K agents. (1) The batched equilibrium solver against a per-sample Python loop for
vertical chains of K = 2..5 agents (5^K joint actions); (2) CSQ and MAPPO-L training speed on highway-v0 with
K = 2, 3, 4 controlled vehicles (CSQ's critics over 5^K joint actions); (3) CSQ's target equilibrium per
hierarchy at K = 4: the critic rows backward induction needs against every critic on the whole grid.

(1) Both sides get the value tensors precomputed (no network). The loop is backward induction by exhaustive
recursion over every prefix of actions, per sample, on nested Python lists (the fastest way to index them in
Python; the array -> list conversion is not timed), with the solver's rule (constrained argmax, min_cost fallback,
first-index ties); the two outputs are checked equal. Each repeat times the loop and the jitted solver side by
side; medians are reported.

(2) One seed, one environment, the chain hierarchy, everything else CSQ's defaults (batch 64, one update per step
after the warm-up), compiled ahead of time (reported apart), then the training chunks timed as in
``python -m train``. Steps are environment steps; after the warm-up every step also makes one gradient update.
MAPPO-L: one seed, the shipped highway configuration (64 envs x 32 steps, then its epochs of minibatch updates),
one update per chunk, the chunks after the first timed.

(3) CSQ's default critics (64-64-64) on 25 observation features, batch 64 (one update's next states), random
parameters; ``solve_equilibrium`` (what the TD targets call) and ``equilibrium(values)`` jitted and timed side by
side per repeat, their actions checked equal; medians.

Run: python benchmarks/hierarchy_bench.py  (writes benchmarks/results/hierarchy.json)
     python benchmarks/hierarchy_bench.py --train-steps 600 --solver-only
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from jaxsmarl.stackelberg import stackelberg_equilibrium  # noqa: E402

A = 5
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "hierarchy.json")


def _get(x, joint):
    for a in joint:
        x = x[a]
    return x


def loop_chain(qs, gs, ds):
    """Per-sample backward induction over a chain 0 | 1 | ... | K-1, by recursion over every prefix (lists in)."""
    k = len(qs)
    out = []
    for b in range(len(qs[0])):
        q = [qs[i][b] for i in range(k)]
        g = [gs[i][b] for i in range(k)]
        d = [ds[i][b] for i in range(k)]

        def solve(prefix):
            m = len(prefix)
            if m == k:
                return prefix
            conts = [solve(prefix + (a,)) for a in range(A)]
            vals = [(_get(q[m], c), _get(g[m], c)) for c in conts]
            feasible = [a for a in range(A) if vals[a][1] <= d[m]]
            if feasible:  # highest Q, first index on ties
                best = max(feasible, key=lambda a: (vals[a][0], -a))
            else:  # lowest cost, then highest Q, then first index
                best = max(range(A), key=lambda a: (-vals[a][1], vals[a][0], -a))
            return conts[best]

        out.append(solve(()))
    return np.asarray(out, np.int32)


def make_inputs(k, batch, seed=0):
    rng = np.random.default_rng(seed + k)
    shape = (batch,) + (A,) * k
    qs = [rng.normal(size=shape).astype(np.float32) for _ in range(k)]
    gs = [rng.uniform(0.0, 1.0, size=shape).astype(np.float32) for _ in range(k)]
    ds = [rng.uniform(-0.05, 0.6, size=(batch,)).astype(np.float32) for _ in range(k)]
    return qs, gs, ds


def bench_solver(k, batch, repeats, inner):
    qs, gs, ds = make_inputs(k, batch)
    lists = ([x.tolist() for x in qs], [x.tolist() for x in gs], [x.tolist() for x in ds])
    solver = jax.jit(lambda q, g, d: stackelberg_equilibrium(q, g, d))
    dev = (tuple(map(jnp.asarray, qs)), tuple(map(jnp.asarray, gs)), tuple(map(jnp.asarray, ds)))
    want = loop_chain(*lists)
    got = np.asarray(solver(*dev).block_until_ready())
    assert np.array_equal(got, want), f"loop and jax solver disagree at K={k}"
    loop_t, jax_t = [], []
    gc.disable()
    for _ in range(repeats):
        t0 = time.perf_counter()
        loop_chain(*lists)
        loop_t.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for _ in range(inner):
            out = solver(*dev)
        out.block_until_ready()
        jax_t.append((time.perf_counter() - t0) / inner)
    gc.enable()
    loop_s, jax_s = statistics.median(loop_t), statistics.median(jax_t)
    return {"agents": k, "joint_actions": A ** k, "batch": batch, "loop_s": loop_s, "jax_s": jax_s,
            "ratio": loop_s / jax_s, "repeats": repeats, "jax_calls_per_repeat": inner}


def bench_train(k, steps, warmup, chunk_steps, algo="csq"):
    from train.build import make_train
    from train.config import load_config
    from train.trainer import seed_keys

    if algo == "csq":
        values = dict(num_envs=1, total_steps=steps, warmup=warmup, chunk_steps=chunk_steps)
    else:  # on-policy: the shipped highway configuration (64 envs x 32 steps per update), one update per chunk
        cycle = 64 * 32
        values = dict(total_steps=steps * cycle, chunk_steps=cycle)
        chunk_steps = cycle
    cfg = load_config("highway", algo, dict(agents=k, num_seeds=1, checkpoint_every=0, eval_episodes=0, **values))
    trainer = make_train(cfg)
    key = seed_keys(cfg)[0]
    t0 = time.perf_counter()
    init = jax.jit(trainer.init).lower(key).compile()
    state = init(key)
    chunk = jax.jit(trainer.run_chunk, donate_argnums=0).lower(state, jnp.int32(0)).compile()
    compile_s = time.perf_counter() - t0
    # the first chunk holds the warm-up; time the chunks after it, where every step also updates the critics
    state, m = chunk(state, jnp.int32(0))
    jax.block_until_ready(m)
    load0 = os.getloadavg()[0]
    t1, c1 = time.perf_counter(), time.process_time()
    timed = 0
    for c in range(1, trainer.n_chunks):
        state, m = chunk(state, jnp.int32(c * trainer.chunk_iters))
        jax.block_until_ready(m)
        timed += chunk_steps
    train_s = time.perf_counter() - t1
    return {"algo": algo, "agents": k, "joint_actions": A ** k,
            "hierarchy": "chain" if algo == "csq" else "flat", "vehicles": int(trainer.env.num_slots),
            "compile_s": round(compile_s, 2), "timed_steps": timed, "train_s": round(train_s, 2),
            "env_steps_per_s": round(timed / train_s, 1), "cpu_s": round(time.process_time() - c1, 1),
            "warmup_steps": warmup if algo == "csq" else None,
            "batch_size": cfg["batch_size"] if algo == "csq" else cfg["num_envs"] * cfg["rollout_length"],
            "load_avg_1m": [round(load0, 2), round(os.getloadavg()[0], 2)]}


def bench_targets(k: int = 4, batch: int = 64, obs_dim: int = 25, repeats: int = 15, inner: int = 5) -> list:
    """(3): the target equilibrium from the rows backward induction needs vs the full grid, per hierarchy."""
    from jaxsmarl.algos.csq import CSQAgent
    from jaxsmarl.algos.csq_config import CSQConfig

    out = []
    for name, h in (("chain", "|".join(map(str, range(k)))),
                    ("horizontal", ",".join(map(str, range((k + 1) // 2))) + "|"
                     + ",".join(map(str, range((k + 1) // 2, k)))),
                    ("flat", ",".join(map(str, range(k))))):
        agent = CSQAgent(CSQConfig(num_actions=(A,) * k, obs_dim=obs_dim, cost_threshold=(0.5,) * k,
                                   eps_start=(0.0,) * k, eps_min=(0.0,) * k, hierarchy=h))
        params = jax.jit(agent.init)(jax.random.PRNGKey(0)).params
        obs = jax.random.normal(jax.random.PRNGKey(1), (batch, k, obs_dim))
        needed = jax.jit(agent.solve_equilibrium)
        full = jax.jit(lambda p, o: agent.equilibrium(agent.values(p, o)))
        np.testing.assert_array_equal(needed(params, obs), full(params, obs))
        times = {"needed": [], "full": []}
        for _ in range(repeats):
            for key, fn in (("needed", needed), ("full", full)):
                t = time.perf_counter()
                for _ in range(inner):
                    fn(params, obs).block_until_ready()
                times[key].append((time.perf_counter() - t) / inner)
        med = {key: statistics.median(v) for key, v in times.items()}
        out.append({"agents": k, "hierarchy": h, "shape": name, "batch": batch, "needed_s": med["needed"],
                    "full_s": med["full"], "ratio": med["full"] / med["needed"]})
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--agents", type=int, nargs="+", default=[2, 3, 4, 5], help="K for the solver")
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--train-agents", type=int, nargs="+", default=[2, 3, 4], help="K for CSQ training")
    p.add_argument("--train-steps", type=int, default=900, help="steps per training run (the first chunk untimed)")
    p.add_argument("--chunk-steps", type=int, default=300)
    p.add_argument("--ppo-updates", type=int, default=4,
                   help="MAPPO-L updates per training run (64 envs x 32 steps each; the first untimed)")
    p.add_argument("--solver-only", action="store_true")
    p.add_argument("--targets-only", action="store_true", help="only (3), CSQ's target equilibrium per hierarchy")
    p.add_argument("--out", default=OUT)
    args = p.parse_args(argv)

    targets = bench_targets()
    print(f"{'hierarchy':>12} {'rows needed (ms)':>17} {'full grid (ms)':>15} {'full/needed':>12}")
    for r in targets:
        print(f"{r['hierarchy']:>12} {r['needed_s'] * 1e3:>17.2f} {r['full_s'] * 1e3:>15.2f} {r['ratio']:>12.2f}")
    if args.targets_only:
        print(json.dumps(targets))
        return
    solver = [bench_solver(k, args.batch, repeats=5 if k >= 5 else 9, inner=20) for k in args.agents]
    print(f"{'K':>2} {'joint':>6} {'batch':>6} {'loop (ms)':>11} {'jax (ms)':>10} {'loop/jax':>9}")
    for r in solver:
        print(f"{r['agents']:>2} {r['joint_actions']:>6} {r['batch']:>6} {r['loop_s'] * 1e3:>11.2f} "
              f"{r['jax_s'] * 1e3:>10.4f} {r['ratio']:>9.0f}")
    train = []
    if not args.solver_only:
        for k in args.train_agents:
            train.append(bench_train(k, args.train_steps, args.chunk_steps, args.chunk_steps))
            r = train[-1]
            print(f"CSQ highway K={k} ({r['joint_actions']} joint actions, {r['vehicles']} vehicles): "
                  f"{r['env_steps_per_s']} env steps/s (compile {r['compile_s']} s, load {r['load_avg_1m']})",
                  flush=True)
        for k in args.train_agents:
            train.append(bench_train(k, args.ppo_updates, 0, 0, algo="mappo-l"))
            r = train[-1]
            print(f"MAPPO-L highway K={k} ({r['vehicles']} vehicles, 64 envs): {r['env_steps_per_s']} env steps/s "
                  f"(compile {r['compile_s']} s, load {r['load_avg_1m']})", flush=True)
    meta = {"benchmark": "hierarchy: batched solver vs per-sample loop (chains, K agents); CSQ and MAPPO-L "
                         "training on highway-v0 with K controlled vehicles",
            "command": "python benchmarks/hierarchy_bench.py " + " ".join(argv if argv is not None else sys.argv[1:]),
            "jax": jax.__version__, "device": str(jax.devices()[0]), "backend": jax.default_backend(),
            "python": platform.python_version(), "cpu_count": os.cpu_count(),
            "timing": "solver: median over repeats, loop and jax side by side, gc off; training: the chunks after "
                      "the first (warm-up) chunk",
            "load_average_1min": os.getloadavg()[0]}
    os.makedirs(os.path.dirname(args.out), exist_ok=True)
    with open(args.out, "w") as f:
        json.dump({"meta": meta, "targets": targets, "solver": solver, "train": train}, f, indent=2)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
