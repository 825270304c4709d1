"""XLA:CPU settings of the training processes: every core a JAX device, and the flags the training programs want.

:func:`use_all_cpu_cores` runs before JAX executes anything (``python -m train`` calls it first).
"""

from __future__ import annotations

import os
import re

import jax

__all__ = ["XLA_CPU_FLAGS", "XLA_CPU_FLAGS_SINCE", "use_all_cpu_cores"]


# XLA:CPU flags for the training programs. YNNPACK's "reduce" fusions run the reductions over the batch axis of
# small networks' backward passes (LayerNorm scale/bias and bias gradients) far slower than XLA's own loop
# emitter. Numerics are unchanged up to summation order.
# The concurrency-optimised scheduler orders a program's kernels for running independent ones side by side on the
# intra-op threads; each seed shard runs on one core, and the default order keeps a network's activations in
# cache. The order of the kernels changes, not what they compute. Measurements: docs/performance.md.
XLA_CPU_FLAGS = ("--xla_cpu_experimental_ynn_fusion_type=-reduce",
                 "--xla_cpu_enable_concurrency_optimized_scheduler=false")
# The first jaxlib that knows both flags (the YNNPACK one is the newer; its fusions are on by default from 0.10.2);
# an older XLA aborts the process on an unknown XLA_FLAGS entry, and has no YNNPACK fusions to turn off.
XLA_CPU_FLAGS_SINCE = (0, 10, 1)


def _jaxlib_version() -> tuple[int, ...]:
    import jaxlib  # the version only; jax has loaded it already

    version = getattr(jaxlib, "__version__", None) or jaxlib.version.__version__
    return tuple(int(x) for x in re.findall(r"\d+", version)[:3])


def use_all_cpu_cores() -> bool:
    """Expose every CPU core as its own JAX device so that seeds run on all cores in parallel (XLA:CPU runs the
    critics' small matrix products on one thread), and put :data:`XLA_CPU_FLAGS` first in ``XLA_FLAGS`` (unless
    ``XLA_FLAGS`` already sets them, or jaxlib predates them). Must run before JAX executes anything; returns
    success."""
    flags = os.environ.get("XLA_FLAGS", "")
    known = _jaxlib_version() >= XLA_CPU_FLAGS_SINCE
    extra = [f for f in XLA_CPU_FLAGS if known and f.split("=")[0] not in flags]
    if extra:  # ahead of the user's: XLA stops reading XLA_FLAGS at the first word that is not a "--" flag
        os.environ["XLA_FLAGS"] = " ".join(extra + [flags]).strip()
    if "xla_force_host_platform_device_count" in flags:  # the user's device count stands
        return True
    try:
        jax.config.update("jax_num_cpu_devices", max(1, _usable_cores()))
        return True
    except RuntimeError:
        return False


def _usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, e.g. under ``taskset`` or a SLURM allocation)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1
