"""Benchmark: jitted batched Stackelberg solver vs a per-sample Python loop over the 25 action pairs.

The loop is the authors' style (docs/algorithms.md, CSQ: for each sample, for a_L in range(5): for a_F in
range(5): ...), but computes the same rule as the solver (eq. p14, min_cost fallback, first-index ties) so
the two outputs are checked equal. Both get the value tensors precomputed (no network evaluation). The loop
gets them as Python lists, the fastest way to index them in Python; the array -> list conversion is NOT in
its time (reported separately as ``tolist_s``), so the ratio favours the loop. Each repeat times the loop and
the jitted solver side by side; medians are reported.

Run: python benchmarks/stackelberg_bench.py  (writes benchmarks/results/stackelberg.json)
"""

from __future__ import annotations

import gc
import json
import os
import platform
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

from jaxsmarl import stackelberg_equilibrium

N_ACTIONS = 5
BATCHES = (64, 4096)
REPEATS = {64: 31, 4096: 15}
JAX_INNER = 50  # jitted calls per timed repeat (one call is far below timer noise at batch 64)
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "stackelberg.json")


def loop_solver(q1, q2, g1, g2, d1, d2):
    """Per-sample Python loops, leader outer / follower inner, the same rule as the solver (lists in)."""
    out = []
    for b in range(len(q1)):
        q1b, q2b, g1b, g2b = q1[b], q2[b], g1[b], g2[b]
        br = []
        for a_l in range(N_ACTIONS):  # follower's constrained best response to every leader action
            best, best_q = -1, 0.0
            for a_f in range(N_ACTIONS):
                if g2b[a_l][a_f] <= d2[b] and (best < 0 or q2b[a_l][a_f] > best_q):
                    best, best_q = a_f, q2b[a_l][a_f]
            if best < 0:  # nothing feasible: lowest cost, then highest Q
                best_key = None  # set on the first action (best < 0 short-circuits the comparison)
                for a_f in range(N_ACTIONS):
                    key = (-g2b[a_l][a_f], q2b[a_l][a_f])
                    if best < 0 or key > best_key:
                        best, best_key = a_f, key
            br.append(best)
        best, best_q = -1, 0.0
        for a_l in range(N_ACTIONS):  # leader anticipates the response
            a_f = br[a_l]
            if g1b[a_l][a_f] <= d1[b] and (best < 0 or q1b[a_l][a_f] > best_q):
                best, best_q = a_l, q1b[a_l][a_f]
        if best < 0:
            for a_l in range(N_ACTIONS):
                a_f = br[a_l]
                key = (-g1b[a_l][a_f], q1b[a_l][a_f])
                if best < 0 or key > best_key:
                    best, best_key = a_l, key
        out.append((best, br[best]))
    return np.asarray(out, np.int32)


@jax.jit
def jax_solver(q1, q2, g1, g2, d1, d2):
    return stackelberg_equilibrium((q1, q2), (g1, g2), (d1, d2))


@jax.jit
def _noop(q1, q2, g1, g2, d1, d2):  # dispatch floor: same arguments, trivial body
    return d1[:1]


def make_inputs(batch, seed=0):
    rng = np.random.default_rng(seed)
    shape = (batch, N_ACTIONS, N_ACTIONS)
    q1, q2 = (rng.normal(size=shape).astype(np.float32) for _ in range(2))
    g1, g2 = (rng.uniform(0.0, 1.0, size=shape).astype(np.float32) for _ in range(2))
    # Per-sample thresholds: some rows all-infeasible, most partially feasible.
    d1, d2 = (rng.uniform(-0.05, 0.6, size=(batch,)).astype(np.float32) for _ in range(2))
    return q1, q2, g1, g2, d1, d2


def bench(batch):
    host = make_inputs(batch)
    dev = tuple(jnp.asarray(x) for x in host)
    t0 = time.perf_counter()
    lists = tuple(x.tolist() for x in host)
    tolist_s = time.perf_counter() - t0
    want = loop_solver(*lists)
    got = np.asarray(jax_solver(*dev).block_until_ready())  # compile + check
    assert np.array_equal(got, want), "loop and jax solver disagree"
    _noop(*dev).block_until_ready()
    loop_t, jax_t, floor_t = [], [], []
    gc.disable()  # as timeit does
    for _ in range(REPEATS[batch]):
        t0 = time.perf_counter()
        loop_solver(*lists)
        loop_t.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        for _ in range(JAX_INNER):
            out = jax_solver(*dev)
        out.block_until_ready()
        jax_t.append((time.perf_counter() - t0) / JAX_INNER)
        t0 = time.perf_counter()
        for _ in range(JAX_INNER):
            out = _noop(*dev)
        out.block_until_ready()
        floor_t.append((time.perf_counter() - t0) / JAX_INNER)
    gc.enable()
    loop_s, jax_s = statistics.median(loop_t), statistics.median(jax_t)
    return {
        "batch": batch,
        "loop_s": loop_s,
        "jax_s": jax_s,
        "ratio": loop_s / jax_s,
        "tolist_s": tolist_s,
        "jit_dispatch_floor_s": statistics.median(floor_t),
        "repeats": REPEATS[batch],
        "jax_calls_per_repeat": JAX_INNER,
        "rows_no_pair_feasible_for_leader": int(np.sum(np.all(host[2] > host[4][:, None, None], axis=(1, 2)))),
    }


def main():
    rows = [bench(b) for b in BATCHES]
    print(f"{'batch':>6} {'loop (ms)':>11} {'jax (ms)':>10} {'loop/jax':>9} {'jit floor (ms)':>15}")
    for r in rows:
        print(
            f"{r['batch']:>6} {r['loop_s'] * 1e3:>11.3f} {r['jax_s'] * 1e3:>10.4f} {r['ratio']:>9.0f}"
            f" {r['jit_dispatch_floor_s'] * 1e3:>15.4f}"
        )
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    meta = {
        "benchmark": "stackelberg_equilibrium (jit) vs per-sample Python loop over 5x5 pairs",
        "jax": jax.__version__,
        "device": str(jax.devices()[0]),
        "backend": jax.default_backend(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "timing": "median over repeats; loop and jax timed side by side in each repeat; gc off",
        "load_average_1min": os.getloadavg()[0],
    }
    with open(OUT, "w") as f:
        json.dump({"meta": meta, "results": rows}, f, indent=2)
    print(f"wrote {OUT}")


if __name__ == "__main__":
    main()
