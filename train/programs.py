"""The compiled programs of a run configuration, built once per process and reused.

:func:`program` holds a configuration's trainer and its seed-parallel functions (init, training chunk, tail chunk,
evaluation); resuming, evaluating or running one configuration again in a process reuses them, so the chunks are
compiled once. :func:`compiled_chunks` compiles the chunks ahead of time for a placed state.
"""

from __future__ import annotations

import json

import jax.numpy as jnp

from train.build import make_train
from train.parallel import seed_parallel, seed_sharding

__all__ = ["PROGRAMS", "program", "compiled_chunks"]


PROGRAMS: dict[str, dict] = {}


def program(config: dict, env=None) -> dict:
    """The trainer and its jitted functions for ``config``; memoised per process (when ``env`` is None) so that
    running one configuration again (resume, evaluation, tests) reuses the compiled program."""
    key = json.dumps({k: v for k, v in config.items() if k != "checkpoint_every"}, sort_keys=True)
    if env is None and key in PROGRAMS:
        return PROGRAMS[key]
    trainer = make_train(config, env)
    S = config["num_seeds"]
    prog = {
        "trainer": trainer, "sharding": seed_sharding(S), "compiled": {},
        "init": seed_parallel(trainer.init, S),
        "chunk": seed_parallel(trainer.run_chunk, S, in_axes=(0, None), donate_argnums=0,
                               sequential=trainer.seeds_in_sequence),
        "tail": (seed_parallel(trainer.run_tail, S, in_axes=(0, None), donate_argnums=0,
                               sequential=trainer.seeds_in_sequence)
                 if trainer.run_tail is not None else None),
        "evaluate": seed_parallel(trainer.evaluate, S),
    }
    if env is None:
        PROGRAMS[key] = prog
    return prog


def compiled_chunks(prog: dict, state) -> dict:
    """Ahead-of-time compiled chunk (and tail chunk) for states shaped and placed like ``state``."""
    if not prog["compiled"]:
        prog["compiled"]["chunk"] = prog["chunk"].lower(state, jnp.int32(0)).compile()
        if prog["tail"] is not None:
            prog["compiled"]["tail"] = prog["tail"].lower(state, jnp.int32(0)).compile()
    return prog["compiled"]
