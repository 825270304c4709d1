"""A saved run back in memory: its configuration, its trainer and the training state of a checkpoint."""

from __future__ import annotations

import os
import sys
from typing import Any

import jax

from jaxsmarl.checkpoints import Checkpointer, CheckpointError
from train.build import make_train
from train.config import read_run_config
from train.trainer import seed_keys

__all__ = ["restore_run", "restore_checked"]


def restore_run(run_dir: str, step: int | None = None):
    """``(config, trainer, state, meta)`` of run folder ``run_dir``: its configuration (later-added keys at their
    defaults), the trainer rebuilt from it (nothing is compiled) and the training state of all seeds from the
    newest checkpoint (or ``step``)."""
    ckpt_dir = os.path.join(run_dir, "checkpoints")
    config = read_run_config(run_dir)
    if not os.path.isdir(ckpt_dir):
        raise ValueError(f"{run_dir} is not a run folder (needs config.json and checkpoints/, as written by "
                         "python -m train)")
    trainer = make_train(config)
    template = jax.eval_shape(jax.vmap(trainer.init), seed_keys(config))
    return config, trainer, *restore_checked(ckpt_dir, step, template)


def restore_checked(ckpt_dir: str, step: int | None, template) -> tuple[Any, dict]:
    """``(state, meta)`` of checkpoint ``step`` in ``ckpt_dir`` if it is intact (else CheckpointError); for None
    the newest intact one, saying on stderr which newer ones were skipped and why."""
    skipped: list[CheckpointError] = []
    with Checkpointer(ckpt_dir) as ckpt:
        if ckpt.latest_step() is None:
            raise ValueError(f"{ckpt_dir} holds no complete checkpoint yet")
        if step is not None:
            return ckpt.restore(step, template)
        _, state, meta = ckpt.restore_valid(template, skipped.append)
    for e in skipped:
        print(f"skipped checkpoint {e.step} of {ckpt_dir} ({e.reason}); using {meta.get('env_steps')}",
              file=sys.stderr)
    return state, meta
