"""A digest of a short training run of every algorithm: the final training state and metrics, bit for bit.

``python -m tests.train_fingerprint OUT.json`` writes ``{algo: sha256}``; the pinned copy
(``tests/data/train_fingerprint.json``) holds the digests of the code before the configuration and loop
restructuring, compared by ``tests/test_train_fingerprint.py`` (slow).
"""

from __future__ import annotations

import hashlib
import json
import sys

import jax
import numpy as np

# scenario, algorithm, overrides: a few updates of each learner, one seed
RUNS = {
    "csq": ("merge", {"total_steps": 96, "chunk_steps": 48, "warmup": 32, "batch_size": 8}),
    "cs-maddpg": ("racetrack", {"total_steps": 48, "chunk_steps": 24, "warmup": 16, "batch_size": 8,
                                "buffer_size": 48}),
    "s-maddpg": ("intersection", {"total_steps": 48, "chunk_steps": 24, "warmup": 16, "batch_size": 8,
                                  "buffer_size": 48, "actor_order": "sequential", "terminal_mask": "batch_mean"}),
    "mappo-l": ("racetrack", {"total_steps": 64, "chunk_steps": 32, "num_envs": 4, "rollout_length": 8,
                              "num_minibatches": 2, "ppo_epochs": 2}),
    "macpo": ("intersection", {"total_steps": 64, "chunk_steps": 32, "num_envs": 4, "rollout_length": 8,
                               "num_minibatches": 2}),
}


def _make_train(config):
    from train.build import make_train

    return make_train(config)


def digest(algo: str) -> str:
    from train.config import load_config

    scenario, over = RUNS[algo]
    config = load_config(scenario, algo, dict(over, num_seeds=1, eval_episodes=0, checkpoint_every=0))
    trainer = _make_train(config)
    state, metrics = jax.jit(trainer.train)(jax.random.PRNGKey(0))
    h = hashlib.sha256()
    for leaf in jax.tree.leaves((state, metrics)):
        a = np.asarray(leaf)
        h.update(str((a.shape, a.dtype)).encode())
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()


if __name__ == "__main__":
    out = {algo: digest(algo) for algo in RUNS}
    with open(sys.argv[1], "w") as f:
        json.dump(out, f, indent=1)
    print(json.dumps(out, indent=1))
