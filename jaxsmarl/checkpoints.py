"""Atomic orbax checkpoints of a whole training state (any pytree) plus a small JSON metadata record.

The training state of every algorithm is one pytree (parameters, optimizer states, target networks, replay
buffer, RNG keys, step counters, schedules), usually with a leading seed axis. :class:`Checkpointer` saves it
under ``<dir>/<step>/`` through ``orbax.checkpoint.CheckpointManager``, which writes into a temporary folder
and renames it only once complete, so an interrupted save never leaves a checkpoint that looks valid.
Restoring needs a like-shaped template (e.g. the freshly initialised state or ``jax.eval_shape`` of it) and
returns arrays with exactly the saved bits, so a resumed run continues bit-identically.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

__all__ = ["Checkpointer"]


def _abstract(x: Any) -> jax.ShapeDtypeStruct:
    if isinstance(x, jax.ShapeDtypeStruct):
        return x
    dtype = x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype
    return jax.ShapeDtypeStruct(np.shape(x), dtype)


class Checkpointer:
    """Save/restore ``(state, meta)`` pairs at integer steps in ``directory`` (keeps the ``max_to_keep`` newest)."""

    def __init__(self, directory: str | os.PathLike, max_to_keep: int | None = 2):
        self.directory = os.path.abspath(os.fspath(directory))
        options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True, enable_async_checkpointing=False)
        self._manager = ocp.CheckpointManager(self.directory, options=options)

    def save(self, step: int, state: Any, meta: dict | None = None) -> None:
        """Write ``state`` (pytree of arrays) and ``meta`` (JSON-serialisable dict) atomically as ``step``."""
        state = jax.tree.map(np.asarray, state)  # host copy: safe even if the device buffers are donated next
        args = ocp.args.Composite(state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(dict(meta or {})))
        self._manager.save(int(step), args=args, force=True)
        self._manager.wait_until_finished()

    def latest_step(self) -> int | None:
        """The newest complete checkpoint's step, or None."""
        self._manager.reload()
        return self._manager.latest_step()

    def all_steps(self) -> list[int]:
        self._manager.reload()
        return sorted(self._manager.all_steps())

    def _step(self, step: int | None) -> int:
        """``step`` if a complete checkpoint holds it, the newest one for None; otherwise an error that names the
        saved steps (only the newest ``max_to_keep`` are kept)."""
        steps = self.all_steps()
        if not steps:
            raise FileNotFoundError(f"no checkpoint in {self.directory}")
        if step is None:
            return steps[-1]
        if int(step) not in steps:
            raise ValueError(f"no checkpoint at step {step} in {self.directory}; saved steps: "
                             f"{', '.join(map(str, steps))}")
        return int(step)

    def restore(self, step: int | None, template: Any) -> tuple[Any, dict]:
        """Load ``(state, meta)`` saved at ``step`` (None: the latest) into the structure of ``template``."""
        step = self._step(step)
        abstract = jax.tree.map(_abstract, template)
        args = ocp.args.Composite(state=ocp.args.StandardRestore(abstract), meta=ocp.args.JsonRestore())
        out = self._manager.restore(step, args=args)
        return out["state"], dict(out["meta"])

    def meta(self, step: int | None = None) -> dict:
        """Only the metadata saved at ``step`` (None: the latest), without reading the state."""
        step = self._step(step)
        out = self._manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
        return dict(out["meta"])

    def close(self) -> None:
        self._manager.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
