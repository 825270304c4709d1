"""Atomic, verified orbax checkpoints of a whole training state (any pytree) plus a small JSON metadata record.

The training state of every algorithm is one pytree (parameters, optimizer states, target networks, replay
buffer, RNG keys, step counters, schedules), usually with a leading seed axis. :class:`Checkpointer` saves it
under ``<dir>/<step>/`` through ``orbax.checkpoint.CheckpointManager``, which writes into a temporary folder
and renames it only once complete, so an interrupted save never leaves a checkpoint that looks valid.

Every checkpoint also records, in its metadata, a SHA-256 digest of each leaf of the host copy it writes
(dtype, shape and bytes). :meth:`Checkpointer.restore` recomputes the digests of what it read and compares them,
so damage on disk (changed bytes, a truncated or missing file, unreadable metadata) raises
:class:`CheckpointError` instead of handing back wrong numbers; :meth:`Checkpointer.restore_valid` falls back to
the newest checkpoint that passes. Restoring needs a like-shaped template (e.g. the freshly initialised state or
``jax.eval_shape`` of it) and returns arrays with exactly the saved bits, so a resumed run continues
bit-identically. A failed save raises :class:`CheckpointWriteError` and leaves the earlier checkpoints as they
were (old ones are only removed once a new one is complete).
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import sys
import time
from typing import Any, Callable

import jax
import numpy as np
import orbax.checkpoint as ocp

_REMOVE_TRIES = 10  # attempts to delete a failed save's temporary folder (about 1 s in all)

__all__ = ["Checkpointer", "CheckpointError", "CheckpointWriteError", "state_digest", "INTEGRITY_KEY"]

# metadata key holding {"algorithm": "sha256", "leaves": {leaf path: hex digest}}; not part of the user's meta
INTEGRITY_KEY = "integrity"


class CheckpointError(ValueError):
    """A checkpoint that cannot be trusted (damaged, incomplete or unreadable), or none that can."""

    def __init__(self, message: str, step: int | None = None, reason: str | None = None):
        super().__init__(message)
        self.step = step
        self.reason = reason or message


class CheckpointWriteError(RuntimeError):
    """A save that did not complete (no space, permission denied, ...); earlier checkpoints are untouched."""


def _abstract(x: Any, on_device: bool = False) -> jax.ShapeDtypeStruct:
    """The restore target of template leaf ``x``: its own placement when it spans several processes; otherwise
    none, or this process's first device when ``on_device`` (needed to read a checkpoint that several processes
    wrote)."""
    if isinstance(x, jax.Array) and not x.is_fully_addressable:  # restored into the same multi-process placement
        return jax.ShapeDtypeStruct(x.shape, x.dtype, sharding=x.sharding)
    if isinstance(x, jax.ShapeDtypeStruct) and (x.sharding is not None or not on_device):
        return x
    dtype = x.dtype if hasattr(x, "dtype") else np.asarray(x).dtype
    device = jax.sharding.SingleDeviceSharding(jax.local_devices()[0]) if on_device else None
    return jax.ShapeDtypeStruct(np.shape(x), dtype, sharding=device)


def _host(x: Any) -> np.ndarray:
    """Whole value of ``x`` on this host; an array sharded over several processes is gathered from all of them."""
    if isinstance(x, jax.Array) and not x.is_fully_addressable:
        from jax.experimental import multihost_utils

        return np.asarray(multihost_utils.process_allgather(x, tiled=True))
    return np.asarray(x)


def _leaf_digest(x: Any) -> str:
    a = np.ascontiguousarray(np.asarray(x))
    h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
    h.update(a.view(np.uint8).reshape(-1) if a.size else b"")
    return h.hexdigest()


def state_digest(state: Any) -> dict[str, str]:
    """``{leaf path: SHA-256 of its dtype, shape and bytes}`` for every leaf of the host pytree ``state``."""
    leaves, _ = jax.tree_util.tree_flatten_with_path(state)
    return {jax.tree_util.keystr(path): _leaf_digest(x) for path, x in leaves}


def _short(e: BaseException) -> str:
    """One line for an exception raised deep inside orbax / tensorstore."""
    text = " ".join(str(e).split()) or type(e).__name__
    if len(text) > 200:  # the head says what failed, the tail why (e.g. the operating system's error)
        text = f"{text[:90]} ... {text[-100:]}"
    return f"{type(e).__name__}: {text}"


def _spans_processes(state: Any) -> bool:
    return any(isinstance(x, jax.Array) and not x.is_fully_addressable for x in jax.tree.leaves(state))


class _QuietOrbax:
    """Silence orbax's own error logging while a damaged checkpoint is probed (the error is reported once, as a
    :class:`CheckpointError`)."""

    def __enter__(self):
        self._loggers = [logging.getLogger(n) for n in ("absl", "orbax", "orbax.checkpoint")]
        self._levels = [lg.level for lg in self._loggers]
        for lg in self._loggers:
            lg.setLevel(logging.CRITICAL)
        return self

    def __exit__(self, *exc):
        for lg, level in zip(self._loggers, self._levels):
            lg.setLevel(level)


def _drop_closed_loop_errors(unraisable) -> None:
    """``sys.unraisablehook`` that drops the ``RuntimeError: Event loop is closed`` which tensorstore's reader
    threads raise when orbax abandons a failed read (its event loop is closed while other reads are still in
    flight); the failure itself is reported once, as a :class:`CheckpointError`. Anything else goes on to the
    hook that was installed before."""
    exc = unraisable.exc_value
    if isinstance(exc, RuntimeError) and str(exc) == "Event loop is closed":
        return
    _drop_closed_loop_errors.previous(unraisable)


def _quiet_closed_loop_errors() -> None:
    if sys.unraisablehook is not _drop_closed_loop_errors:
        _drop_closed_loop_errors.previous = sys.unraisablehook
        sys.unraisablehook = _drop_closed_loop_errors


class Checkpointer:
    """Save/restore ``(state, meta)`` pairs at integer steps in ``directory`` (keeps the ``max_to_keep`` newest,
    at least two by default so that a damaged newest one has a predecessor to fall back to)."""

    def __init__(self, directory: str | os.PathLike, max_to_keep: int | None = 2):
        self.directory = os.path.abspath(os.fspath(directory))
        options = ocp.CheckpointManagerOptions(max_to_keep=max_to_keep, create=True, enable_async_checkpointing=False)
        self._manager = ocp.CheckpointManager(self.directory, options=options)

    def save(self, step: int, state: Any, meta: dict | None = None) -> None:
        """Write ``state`` (pytree of arrays) and ``meta`` (JSON-serialisable dict) atomically as ``step``, with the
        digest of every leaf. Raises :class:`CheckpointWriteError` if the write fails."""
        host = jax.tree.map(_host, state)  # host copy: safe even if the device buffers are donated next
        # several processes: each writes its own shards of the global arrays (orbax's multi-process save)
        state = state if _spans_processes(state) else host
        meta = dict(meta or {})
        if INTEGRITY_KEY in meta:
            raise ValueError(f"checkpoint metadata key {INTEGRITY_KEY!r} is reserved for the state's digests")
        meta[INTEGRITY_KEY] = {"algorithm": "sha256", "leaves": state_digest(host)}
        args = ocp.args.Composite(state=ocp.args.StandardSave(state), meta=ocp.args.JsonSave(meta))
        try:
            self._manager.reload()  # the folder may have changed since (e.g. a damaged checkpoint set aside)
            with _QuietOrbax():
                self._manager.save(int(step), args=args, force=True)
                self._manager.wait_until_finished()
        except Exception as e:  # noqa: BLE001 - any failure of the write is reported the same way
            _quiet_closed_loop_errors()
            self._remove_unfinished(int(step))
            kept = self._complete_steps()
            raise CheckpointWriteError(
                f"could not write the checkpoint at step {step} into {self.directory} ({_short(e)}); the "
                f"checkpoints written before are intact ({', '.join(map(str, kept)) or 'none'})") from e

    def _complete_steps(self) -> list[int]:
        try:
            return self.all_steps()
        except Exception:  # noqa: BLE001 - only for an error message
            return []

    def _remove_unfinished(self, step: int) -> None:
        """Delete the temporary folder a failed save of ``step`` left (frees the space it took). orbax's writer
        threads may still be closing files in it when the error arrives, so the removal is retried a few times."""
        try:
            self._manager.wait_until_finished()
        except Exception:  # noqa: BLE001 - the save's own error is the one reported
            pass
        for attempt in range(_REMOVE_TRIES):
            try:
                left = [n for n in os.listdir(self.directory) if n.startswith(f"{step}.orbax-checkpoint-tmp")]
            except OSError:
                return
            if not left:
                return
            for name in left:
                shutil.rmtree(os.path.join(self.directory, name), ignore_errors=True)
            time.sleep(0.02 * (attempt + 1))

    def latest_step(self) -> int | None:
        """The newest complete checkpoint's step, or None (complete: fully written; see :meth:`restore` for
        whether it is intact)."""
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

    def _read_meta(self, step: int) -> dict:
        try:
            with _QuietOrbax():
                out = self._manager.restore(step, args=ocp.args.Composite(meta=ocp.args.JsonRestore()))
            meta = dict(out["meta"])
        except Exception as e:  # noqa: BLE001 - any failure to read it makes the checkpoint invalid
            raise self._invalid(step, f"its metadata is unreadable ({_short(e)})") from e
        return meta

    def _invalid(self, step: int, reason: str) -> CheckpointError:
        return CheckpointError(f"checkpoint {step} in {self.directory} is invalid: {reason}", step, reason)

    def restore(self, step: int | None, template: Any) -> tuple[Any, dict]:
        """Load ``(state, meta)`` saved at ``step`` (None: the latest) into the structure of ``template`` and check
        every leaf against the digest saved with it. Raises :class:`CheckpointError` if the checkpoint is
        damaged or unreadable (a checkpoint written before digests were recorded is read unchecked; its meta
        then has ``"verified": False``)."""
        step = self._step(step)
        meta = self._read_meta(step)
        integrity = meta.pop(INTEGRITY_KEY, None)
        try:
            with _QuietOrbax():
                try:
                    state = self._restore_state(step, template, False)
                except ValueError as e:  # written by several processes: read onto this process's device
                    if "topology" not in str(e).lower():
                        raise
                    state = self._restore_state(step, template, True)
            state = jax.tree.map(_host, state)
        except Exception as e:  # noqa: BLE001 - a missing, truncated or garbled file ends up here
            _quiet_closed_loop_errors()
            raise self._invalid(step, f"its state is unreadable ({_short(e)})") from e
        if integrity is None:
            meta["verified"] = False
            return state, meta
        try:
            saved = dict(integrity["leaves"])
        except (TypeError, KeyError) as e:
            raise self._invalid(step, "its digest record is malformed") from e
        found = state_digest(state)
        if set(saved) != set(found):
            raise self._invalid(step, f"its digest record lists {len(saved)} leaves, the state has {len(found)}")
        bad = [k for k in found if found[k] != saved[k]]
        if bad:
            raise self._invalid(step, f"the digest of {len(bad)} of {len(found)} leaves does not match what was "
                                      f"saved (e.g. {bad[0]}): the data on disk changed")
        return state, meta

    def _restore_state(self, step: int, template: Any, on_device: bool) -> Any:
        abstract = jax.tree.map(lambda x: _abstract(x, on_device), template)
        args = ocp.args.Composite(state=ocp.args.StandardRestore(abstract))
        return self._manager.restore(step, args=args)["state"]

    def restore_valid(self, template: Any, on_skip: Callable[[CheckpointError], None] | None = None
                      ) -> tuple[int, Any, dict]:
        """``(step, state, meta)`` of the newest checkpoint that :meth:`restore` accepts, trying older ones in
        turn; ``on_skip(error)`` is told about each one skipped. Raises :class:`CheckpointError` naming the folder
        and what was found if none is valid."""
        steps = self.all_steps()
        if not steps:
            raise CheckpointError(f"no complete checkpoint in {self.directory}")
        errors = []
        for step in reversed(steps):
            try:
                state, meta = self.restore(step, template)
                return step, state, meta
            except CheckpointError as e:
                errors.append(e)
                if on_skip is not None:
                    on_skip(e)
        found = "; ".join(f"{e.step}: {e.reason}" for e in errors)
        raise CheckpointError(f"no valid checkpoint in {self.directory}: found {len(steps)}, all invalid ({found})")

    def meta(self, step: int | None = None) -> dict:
        """Only the metadata saved at ``step`` (None: the latest), without reading or checking the state."""
        meta = self._read_meta(self._step(step))
        meta.pop(INTEGRITY_KEY, None)
        return meta

    def close(self) -> None:
        self._manager.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
