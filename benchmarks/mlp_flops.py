"""What this machine's matmuls deliver for MLPs of our widths: GFLOP/s of a jitted chain of dense layers
(``tanh(h @ W)``, 4 layers, 200 scanned repetitions) in float32 and in bfloat16 (float32 accumulation), for a few
batch sizes and widths, summed over all CPU cores (one JAX device per core, each running its own chain, as
training splits its seeds; XLA:CPU runs such small products on one thread). It bounds what a training step built
from such layers can reach here; the CS-MADDPG speed figures in the README's "Training" section quote it.

    python benchmarks/mlp_flops.py [--batches 256 2048 8192] [--widths 64 256]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from train.xla_flags import use_all_cpu_cores  # noqa: E402

use_all_cpu_cores()

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402


def gflops(dtype, batch: int, width: int, layers: int = 4, reps: int = 200, repeats: int = 5) -> float:
    """Median GFLOP/s, all devices together, of ``reps`` passes of ``layers`` dense layers on ``[batch, width]``
    inputs on every device."""
    n = jax.local_device_count()
    ks = jax.random.split(jax.random.PRNGKey(0), layers + 1)
    x = jax.random.normal(ks[0], (n, batch, width)).astype(dtype)
    ws = [(jax.random.normal(k, (n, width, width)) / np.sqrt(width)).astype(dtype) for k in ks[1:]]

    @jax.pmap
    def chain(x, ws):
        def body(h, _):
            for w in ws:
                h = jnp.tanh(jnp.dot(h, w, preferred_element_type=jnp.float32)).astype(dtype)
            return h, None

        return jax.lax.scan(body, x, None, length=reps)[0]

    chain(x, ws).block_until_ready()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        chain(x, ws).block_until_ready()
        times.append(time.perf_counter() - t)
    return 2.0 * n * batch * width * width * layers * reps / float(np.median(times)) / 1e9


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--batches", type=int, nargs="+", default=[256, 2048, 8192])
    p.add_argument("--widths", type=int, nargs="+", default=[64, 256])
    args = p.parse_args(argv)
    if min(args.batches + args.widths) < 1:
        raise SystemExit("error: --batches and --widths must be positive integers")
    print(f"jax {jax.__version__} on {jax.devices()[0].platform} ({len(jax.devices())} device(s))")
    print("| batch | width | float32 GFLOP/s | bfloat16 GFLOP/s | ratio |")
    print("|---|---|---|---|---|")
    for b in args.batches:
        for w in args.widths:
            f32, bf16 = gflops(jnp.float32, b, w), gflops(jnp.bfloat16, b, w)
            print(f"| {b} | {w} | {f32:.1f} | {bf16:.1f} | {bf16 / f32:.2f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
