"""Short CSQ programs whose outputs are pinned in ``tests/data/csq_two_agent_reference.npz``.

The file was written by the two-agent CSQ before hierarchies existed (``python -m tests.csq_reference``); the
tests compare today's outputs to it bit for bit, so the two-agent path keeps giving the same results. These runs
step two environments of two vehicles, below the size at which the simulator's float32 trigonometry switches to
polynomials (envs_jax/trig.py, ``SMALL``), so they use XLA's own functions as when the file was written.
"""

from __future__ import annotations

import os

import jax
import numpy as np

REFERENCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "csq_two_agent_reference.npz")

# (name, scenario, preset): the paper's rule on merge, the authors' coded rule on roundabout.
RUNS = (("merge", "merge", None), ("roundabout_authors", "roundabout", "authors"))
SHORT = dict(total_steps=240, num_envs=2, chunk_steps=240, num_seeds=1, warmup=32, batch_size=16,
             checkpoint_every=0, eval_episodes=0)


def solver_inputs(k: int, batch: int = 300, seed: int = 0):
    """Random Q/G tensors ``[batch, 5, ..., 5]`` per agent with ties (values rounded to a coarse grid)."""
    rng = np.random.default_rng(seed + k)
    shape = (batch,) + (5,) * k
    qs = [np.round(rng.normal(size=shape), 1).astype(np.float32) for _ in range(k)]
    gs = [np.round(rng.normal(size=shape), 1).astype(np.float32) for _ in range(k)]
    ds = [np.round(rng.normal(size=(batch,)) * 0.5, 1).astype(np.float32) for _ in range(k)]
    return qs, gs, ds


SOLVER_RULES = tuple((lr, inf, tb) for lr in ("stackelberg", "authors") for inf in ("min_cost", "argmax")
                     for tb in ("first", "last"))


def solver_outputs() -> dict:
    from jaxsmarl.stackelberg import stackelberg_equilibrium

    out = {}
    for k in (2, 3):
        qs, gs, ds = solver_inputs(k)
        for lr, inf, tb in SOLVER_RULES:
            eq = stackelberg_equilibrium(qs, gs, ds, leader_rule=lr, infeasible=inf, tie_break=tb)
            out[f"solver_k{k}_{lr}_{inf}_{tb}"] = np.asarray(eq)
    return out


def short_run(scenario: str, preset: str | None) -> dict:
    """One seed of CSQ for ``SHORT`` steps: every episode record, the learner's losses, the final critics' output
    layer and first-layer biases (the losses of every update already depend on all weights)."""
    from train.build import make_train
    from train.config import load_config
    from train.trainer import seed_keys

    cfg = load_config(scenario, "csq", dict(SHORT), preset=preset)
    trainer = make_train(cfg)
    state, metrics = jax.jit(trainer.train)(seed_keys(cfg)[0])
    out = {f"episode_{k}": np.asarray(v) for k, v in metrics["episode"].items()}
    out.update({f"update_{k}": np.asarray(v) for k, v in metrics["update"].items()})
    leaves = jax.tree_util.tree_leaves_with_path(state.agent.params)
    for path, x in leaves:
        name = "params" + jax.tree_util.keystr(path)
        if "_Dense_3" in name or ("_Dense_0" in name and "bias" in name):
            out[name] = np.asarray(x)
    return out


def all_outputs() -> dict:
    out = {f"solver/{k}": v for k, v in solver_outputs().items()}
    for name, scenario, preset in RUNS:
        out.update({f"{name}/{k}": v for k, v in short_run(scenario, preset).items()})
    return out


if __name__ == "__main__":
    np.savez_compressed(REFERENCE, **all_outputs())
    print("wrote", REFERENCE, os.path.getsize(REFERENCE), "bytes")
