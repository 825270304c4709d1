"""Checks and changes of a run folder (``--out``) around a run: a new run, an overwrite, a resume.

A resume must find checkpoints, the same configuration (but for :data:`train.config.RESUME_FREE` and a new budget
that continues the saved run exactly), and as many processes as wrote the checkpoints; a damaged checkpoint is set
aside for inspection.
"""

from __future__ import annotations

import os
import shutil

import jax

from jaxsmarl.checkpoints import Checkpointer, CheckpointError
from train import distributed
from train.config import RESUME_FREE
from train.lock import LOCK_NAME
from train.programs import program

__all__ = ["check_out_dir", "clear_run_dir", "same_config", "check_new_budget", "check_process_count", "set_aside"]


def check_out_dir(out: str, resume: bool, overwrite: bool) -> None:
    ckpt = os.path.join(out, "checkpoints")
    has_run = os.path.exists(os.path.join(out, "config.json")) or os.path.isdir(ckpt)
    if resume:
        if not os.path.isdir(ckpt):
            raise ValueError(f"--resume: no checkpoints in {out}; start a new run without --resume")
        return
    if has_run and not overwrite:
        raise ValueError(f"{out} already holds a run; pass --resume to continue it, --overwrite to replace it, "
                         "or choose another --out")


def same_config(saved: dict, cfg: dict) -> None:
    # total_steps is checked by check_new_budget
    ignore = (*RESUME_FREE, "total_steps")
    diff = {k: (saved.get(k), cfg[k]) for k in cfg if k not in ignore and saved.get(k) != cfg[k]}
    if diff:
        raise ValueError(f"--resume with a different configuration than the saved run: {diff}; resume with the "
                         "same options (the saved config.json is used when none are given; only --steps, "
                         "--checkpoint-every and --eval-episodes may change) or start a new --out")


def check_new_budget(saved: dict, config: dict, meta: dict, trainer, env) -> None:
    """Resuming with another ``total_steps`` (e.g. training a finished run further) continues exactly the run a
    fresh one with the new budget would have made, provided the new budget is not below the checkpoint, every
    chunk done so far was a whole one (so chunk ``c`` still starts at ``c * chunk_steps``), and the training state
    has the same shapes (an off-policy buffer holds ``min(buffer_size, total_steps)`` transitions). Nothing else
    in the training programs depends on the budget."""
    done = int(meta["env_steps"])
    if config["total_steps"] < done:
        raise ValueError(f"--resume --steps {config['total_steps']}: the run already has {done} env steps per seed "
                         f"in its newest checkpoint; give at least that many")
    E = config["num_envs"]
    if done != int(meta["chunks_done"]) * trainer.chunk_iters * E:
        raise ValueError(f"--resume --steps {config['total_steps']}: the saved run ended on a partial chunk "
                         f"({done} env steps is not a multiple of chunk_steps={config['chunk_steps']}), so a longer "
                         f"run would not continue it exactly; start a new --out")
    key = jax.random.PRNGKey(0)
    old_shapes = jax.eval_shape(program(saved, env)["trainer"].init, key)
    new_shapes = jax.eval_shape(trainer.init, key)
    if jax.tree.structure(old_shapes) != jax.tree.structure(new_shapes) or any(
            (a.shape, a.dtype) != (b.shape, b.dtype)
            for a, b in zip(jax.tree.leaves(old_shapes), jax.tree.leaves(new_shapes))):
        raise ValueError(f"--resume --steps {config['total_steps']}: the training state would change shape (a replay "
                         f"buffer holds min(buffer_size, total_steps) = min({saved.get('buffer_size')}, "
                         f"{saved['total_steps']}) transitions in the saved run); start a new --out with the longer "
                         f"budget, or set buffer_size to at most {saved['total_steps']} there")


def clear_run_dir(out: str) -> None:
    """Delete everything in run folder ``out`` but its lock file (held by this process)."""
    for name in os.listdir(out):
        if name == LOCK_NAME:
            continue
        path = os.path.join(out, name)
        if os.path.isdir(path) and not os.path.islink(path):
            shutil.rmtree(path)
        else:
            os.remove(path)


def check_process_count(ckpt: Checkpointer, meta: dict | None = None) -> None:
    """A run resumes with as many processes as wrote its checkpoints (``meta`` of the restored one, or the newest
    one's when it is readable): each process restores the seeds of its own devices."""
    if meta is None:
        try:
            meta = ckpt.meta()
        except (CheckpointError, FileNotFoundError):
            return  # unreadable: restore_valid finds an intact one, checked afterwards
    saved, now = int(meta.get("num_processes", 1)), distributed.process_count()
    if saved != now:
        raise ValueError(f"--resume: the run was trained by {saved} process{'es' if saved > 1 else ''} and this "
                         f"is {now}; resume it with --num-processes {saved} (the seeds of each process's devices "
                         f"are in its checkpoints), or start a new --out")


def set_aside(out: str, step: int) -> str:
    """Move damaged checkpoint ``step`` out of ``checkpoints/`` (so the resumed run can write that step again)
    into ``damaged_checkpoints/``, where it stays for inspection."""
    src = os.path.join(out, "checkpoints", str(step))
    base = os.path.join(out, "damaged_checkpoints", str(step))
    dst, i = base, 1
    while os.path.exists(dst):
        dst, i = f"{base}.{i}", i + 1
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    os.replace(src, dst)
    return dst
