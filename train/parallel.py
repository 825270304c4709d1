"""The seeds of a run spread over the devices: the device mesh along the seed axis, and seed-parallel programs.

Seeds are independent: each device runs its own seeds as an independent program, batched (``vmap``) or one after
another (:func:`seed_loop`); nothing crosses devices.
"""

from __future__ import annotations

import math

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = ["seed_sharding", "seed_loop", "seed_parallel"]


def seed_sharding(num_seeds: int):
    """Split the seed axis over the devices (as many as divide ``num_seeds``); None for one device. In a
    multi-process run the mesh holds every device of every process, and ``num_seeds`` must be a multiple of their
    number (each process runs the seeds of its own devices)."""
    devices = jax.devices()
    if jax.process_count() > 1 and num_seeds % len(devices):
        raise ValueError(f"num_seeds ({num_seeds}) must be a multiple of the {len(devices)} devices of the "
                         f"{jax.process_count()} processes in a multi-process run (each device runs as many seeds); "
                         f"e.g. --seeds {(num_seeds // len(devices) + 1) * len(devices)}")
    n = math.gcd(num_seeds, len(devices))
    if n <= 1:
        return None
    return NamedSharding(Mesh(np.array(devices[:n]), ("seeds",)), PartitionSpec("seeds"))


def seed_loop(fn, in_axes=0):
    """``jax.vmap(fn, in_axes)`` computed one seed after another (``lax.map``): the same values up to round-off,
    each seed by the unbatched program (so, from two seeds up, a seed's result does not depend on the others).
    ``in_axes``: 0 or None per argument."""
    def run(*args):
        axes = tuple(in_axes) if isinstance(in_axes, (tuple, list)) else (in_axes,) * len(args)
        if len(axes) != len(args) or any(a not in (0, None) for a in axes):
            raise ValueError(f"seed_loop: in_axes must be 0 or None per argument, got {in_axes!r}")
        mapped = tuple(x for x, a in zip(args, axes) if a == 0)

        def one(xs):
            it = iter(xs)
            return fn(*(next(it) if a == 0 else x for x, a in zip(args, axes)))

        return jax.lax.map(one, mapped)

    return run


def seed_parallel(fn, num_seeds: int, in_axes=0, donate_argnums=(), sequential: bool = False):
    """``jit(vmap(fn, in_axes))`` over ``num_seeds`` seeds, the seeds split over the devices of
    :func:`seed_sharding`: each device runs its own seeds as an independent program (``shard_map``), and every
    output is sharded along the seed axis.

    Not ``jit(vmap(fn), out_shardings=...)``: the SPMD partitioner then keeps the devices of one program in
    lock-step, e.g. a ``while_loop`` whose trip count depends on the seed (the envs' ``sparse_map``) gets an
    all-reduce over devices in its condition at every trip; seeds are independent, so nothing should cross
    devices (and an XLA:CPU collective parks a thread of the 2-thread intra-op pool while it waits).

    ``sequential``: a device runs its seeds one after another (:func:`seed_loop`) instead of batched: on XLA:CPU
    the batched update runs slower than the same work seed by seed, and the rollout costs the same either way
    (docs/performance.md).
    """
    sharding = seed_sharding(num_seeds)
    vfn = seed_loop(fn, in_axes) if sequential else jax.vmap(fn, in_axes=in_axes)
    if sharding is None:
        return jax.jit(vfn, donate_argnums=donate_argnums)
    seeds, rep = PartitionSpec("seeds"), PartitionSpec()
    axes = in_axes if isinstance(in_axes, (tuple, list)) else (in_axes,)
    specs = tuple(rep if a is None else seeds for a in axes)
    if not isinstance(in_axes, (tuple, list)):
        specs = specs[0]
    # check_vma off: every value is per device anyway (all outputs are split along the seeds), and the check
    # rejects scans whose carry starts replicated (a constant) and becomes per-device.
    return jax.jit(jax.shard_map(vfn, mesh=sharding.mesh, in_specs=specs, out_specs=seeds, check_vma=False),
                   donate_argnums=donate_argnums)
