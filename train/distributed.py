"""Several cooperating training processes through JAX's own distributed runtime (``jax.distributed``).

``python -m train`` becomes one of N processes when it is told where the coordinator is: the options
``--coordinator-address HOST:PORT --num-processes N --process-id I``, the environment variables
``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID``, or ``--distributed`` alone, which
lets JAX detect the cluster (SLURM, Open MPI, Cloud TPU, Kubernetes). The seed axis is then sharded over every
device of every process (one global mesh, :func:`train.parallel.seed_sharding`); the seeds stay independent, so the
only traffic between processes is gathering the per-chunk metrics and checkpoint digests to the host.

Failure of a peer: JAX's coordination service (in process 0) declares a process dead when it has sent no
heartbeat for :data:`HEARTBEAT_TIMEOUT_S` seconds and then stops every other process with an error; a peer that
dies while the others wait in a collective (gloo on the CPU) breaks that collective's connections, which raises
at once. docs/distributed.md states the timeouts.
"""

from __future__ import annotations

import dataclasses
import os

__all__ = ["HEARTBEAT_TIMEOUT_S", "INIT_TIMEOUT_S", "SHUTDOWN_TIMEOUT_S", "Cluster", "from_options", "initialize",
           "process_count", "process_index", "is_main", "sync", "to_host", "to_global"]

# A process that has sent no heartbeat for this long is declared dead and the others stop with an error.
HEARTBEAT_TIMEOUT_S = 30
# How long the processes wait for each other to connect at start-up.
INIT_TIMEOUT_S = 300
# How long a finishing process waits for the others to finish too.
SHUTDOWN_TIMEOUT_S = 60

_LOOPBACK = ("127.0.0.1", "localhost", "[::1]")


@dataclasses.dataclass(frozen=True)
class Cluster:
    """Where the processes meet. ``auto``: let JAX detect the missing values from the cluster environment."""

    coordinator_address: str | None = None
    num_processes: int | None = None
    process_id: int | None = None
    auto: bool = False
    heartbeat_timeout_s: int = HEARTBEAT_TIMEOUT_S

    @property
    def requested(self) -> bool:
        return self.auto or any(v is not None for v in (self.coordinator_address, self.num_processes,
                                                        self.process_id))


def _env_int(name: str) -> int | None:
    v = os.environ.get(name)
    if v is None or v == "":
        return None
    try:
        return int(v)
    except ValueError:
        raise ValueError(f"environment variable {name} must be an integer, got {v!r}") from None


def from_options(coordinator_address: str | None = None, num_processes: int | None = None,
                 process_id: int | None = None, auto: bool = False,
                 heartbeat_timeout_s: int | None = None) -> Cluster:
    """The :class:`Cluster` of the command-line options, falling back on ``JAX_COORDINATOR_ADDRESS``,
    ``JAX_NUM_PROCESSES`` and ``JAX_PROCESS_ID``; ValueError for values that cannot work."""
    c = Cluster(coordinator_address or os.environ.get("JAX_COORDINATOR_ADDRESS") or None,
                num_processes if num_processes is not None else _env_int("JAX_NUM_PROCESSES"),
                process_id if process_id is not None else _env_int("JAX_PROCESS_ID"), auto,
                HEARTBEAT_TIMEOUT_S if heartbeat_timeout_s is None else heartbeat_timeout_s)
    if not c.requested:
        return c
    if c.coordinator_address is not None and (":" not in c.coordinator_address
                                              or not c.coordinator_address.rsplit(":", 1)[1].isdigit()):
        raise ValueError(f"--coordinator-address must be HOST:PORT (process 0's address and a free port), got "
                         f"{c.coordinator_address!r}")
    if c.num_processes is not None and c.num_processes < 1:
        raise ValueError(f"--num-processes must be >= 1, got {c.num_processes}")
    if c.process_id is not None and not (0 <= c.process_id < (c.num_processes or c.process_id + 1)):
        raise ValueError(f"--process-id must lie in [0, num_processes), got {c.process_id} of {c.num_processes}")
    if c.heartbeat_timeout_s < 1:
        raise ValueError(f"the heartbeat timeout must be >= 1 s, got {c.heartbeat_timeout_s}")
    if not c.auto and None in (c.coordinator_address, c.num_processes, c.process_id):
        missing = [n for n, v in (("--coordinator-address", c.coordinator_address),
                                  ("--num-processes", c.num_processes), ("--process-id", c.process_id)) if v is None]
        raise ValueError(f"a multi-process run needs {', '.join(missing)} too (or the JAX_* environment variables, "
                         "or --distributed to detect a SLURM / Open MPI cluster)")
    return c


def initialize(cluster: Cluster) -> bool:
    """Join the cluster (``jax.distributed.initialize`` with our timeouts; gloo collectives on the CPU). Must run
    before JAX computes anything. Returns whether a distributed runtime was started."""
    if not cluster.requested:
        return False
    import jax

    # CPU devices of different processes exchange data through gloo over TCP (XLA's CPU collectives).
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    bind = None
    addr = cluster.coordinator_address
    if addr is not None and addr.rsplit(":", 1)[0] in _LOOPBACK:
        bind = addr  # a one-machine run listens on the loopback only, not on every interface
    jax.distributed.initialize(coordinator_address=addr, num_processes=cluster.num_processes,
                               process_id=cluster.process_id, initialization_timeout=INIT_TIMEOUT_S,
                               heartbeat_timeout_seconds=cluster.heartbeat_timeout_s,
                               shutdown_timeout_seconds=SHUTDOWN_TIMEOUT_S, coordinator_bind_address=bind)
    return True


def process_count() -> int:
    import jax

    return jax.process_count()


def process_index() -> int:
    import jax

    return jax.process_index()


def is_main() -> bool:
    """Whether this process writes the run folder's files (process 0; always true in a one-process run)."""
    return process_index() == 0


def sync(name: str) -> None:
    """Wait until every process has reached the point called ``name`` (no-op in a one-process run)."""
    if process_count() > 1:
        from jax.experimental import multihost_utils

        multihost_utils.sync_global_devices(name)


def to_host(tree):
    """Host (numpy) copy of a pytree of arrays, gathered from every process when they are sharded across
    processes; every process gets the whole value."""
    import jax
    import numpy as np

    def one(x):
        if isinstance(x, jax.Array) and not x.is_fully_addressable:
            from jax.experimental import multihost_utils

            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return np.asarray(x)

    return jax.tree.map(one, tree)


def to_global(tree, sharding):
    """Place a host pytree (the same values on every process) with ``sharding``, which may span the devices of
    several processes: each process puts only its own shards."""
    import jax
    import numpy as np

    if sharding is None or sharding.is_fully_addressable:
        return jax.device_put(tree, sharding)

    def one(x):
        if isinstance(x, jax.Array) and x.sharding == sharding:
            return x
        x = np.asarray(x)
        return jax.make_array_from_callback(x.shape, sharding, lambda idx: x[idx])

    return jax.tree.map(one, tree)
