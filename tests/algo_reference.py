"""Short training runs of MAPPO-L, MACPO and the MADDPG family whose outputs are pinned in
``tests/data/algo_reference.npz``, in both network layouts (docs/design.md, network layouts).

``python3 -m tests.algo_reference`` writes the file; :mod:`tests.test_algo_reference` compares today's outputs to it,
so that restructuring the algorithms keeps their results. Every run sets all of its configuration (``CONFIGS``,
stored beside the outputs), so that a changed default does not change a pinned run.

The runs use 64-bit floats (networks included): XLA:CPU's float32 code differs in the last bits between processors
(an Intel Xeon and an AMD EPYC disagree from the first rollout on), and the MACPO runs amplify such differences
into other episode ends within three updates; in float64 the same differences stay far below the comparison's
tolerance (docs/design.md, pinned runs).
"""

from __future__ import annotations

import contextlib
import json
import os

import jax
import numpy as np

REFERENCE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "algo_reference.npz")
LAYOUTS = ("columns", "rows")

_PPO = dict(num_seeds=1, seed=0, num_envs=8, rollout_length=16, total_steps=384, chunk_steps=384,
            checkpoint_every=0, eval_episodes=0, num_minibatches=4, hidden=64, layer_n=1, feature_norm=True,
            obs_norm=True, value_norm=True, std_x_coef=1.0, std_y_coef=0.5, gamma=0.99, gae_lambda=0.95,
            critic_lr=5e-3, adam_eps=1e-5, value_clip=0.2, huber_delta=10.0, value_loss_coef=1.0,
            max_grad_norm=10.0, cost_limit=0.1, per_agent_cost=False, sequential=True, matmul_precision="highest",
            eval_max_steps=200)
_MAPPOL = dict(_PPO, actor_lr=1e-3, clip=0.2, ppo_epochs=2, entropy_coef=0.01, lambda_init=0.78, lambda_lr=5e-2)
_MACPO = dict(_PPO, kl_threshold=0.0065, cg_iters=10, ls_steps=10, ls_fraction=0.5, fraction_coef=0.27,
              fvp_damping=0.1)
_MADDPG = dict(num_seeds=1, seed=0, num_envs=2, total_steps=300, chunk_steps=300, checkpoint_every=0,
               eval_episodes=0, eval_max_steps=200, matmul_precision="highest", updates_per_step=1, lr_actor=1e-3,
               lr_critic=1e-3, gamma=0.95, tau=0.01, target_update_every=10, batch_size=16, warmup=64,
               buffer_size=1000, noise_start=[0.1, 0.1], noise_min=[0.0, 0.0], eps_start=[0.1, 0.1],
               eps_min=[0.0, 0.0], explore_decay=5e-7, hidden_sizes=[64, 64, 64], init="torch",
               critic_input="joint", bootstrap_on_truncation=True, actor_order="simultaneous",
               terminal_mask="sample")
_CONSTRAINED = dict(cost_threshold=[5.0, 5.0], lambda_rule="dual", lr_lambda=1e-2, lambda_init=0.0,
                    lambda_max=100.0)

# name -> (scenario, algo, full configuration)
CONFIGS = {
    "racetrack_mappo-l": ("racetrack", "mappo-l", _MAPPOL),
    "intersection_mappo-l": ("intersection", "mappo-l", _MAPPOL),
    "racetrack_macpo": ("racetrack", "macpo", _MACPO),
    "intersection_macpo": ("intersection", "macpo", _MACPO),
    "intersection_cs-maddpg": ("intersection", "cs-maddpg", dict(_MADDPG, **_CONSTRAINED)),
    "racetrack_c-maddpg": ("racetrack", "c-maddpg", dict(_MADDPG, **_CONSTRAINED, actor_order="sequential")),
    "racetrack_s-maddpg": ("racetrack", "s-maddpg", dict(_MADDPG, critic_input="own")),
    "intersection_maddpg": ("intersection", "maddpg", _MADDPG),
}
# the runs of the default test suite (one per family, one per layout); the others are marked slow
FAST = (("racetrack_mappo-l", "columns"), ("intersection_cs-maddpg", "rows"))


@contextlib.contextmanager
def layout(name: str):
    """Agents built inside use the network layout ``name`` (``"columns"`` or ``"rows"``): the override of
    :func:`jaxsmarl.layout.layout`."""
    from unittest import mock

    from jaxsmarl.layout import ENV_VAR

    with mock.patch.dict(os.environ, {ENV_VAR: name}):
        yield


def _leaves(tree, prefix: str, every: int = 3) -> dict:
    """Every ``every``-th parameter leaf of ``tree`` by its path, kernels left out to keep the file small (the
    losses of each update and the other leaves depend on them)."""
    leaves = jax.tree_util.tree_leaves_with_path(tree)[::every]
    named = ((prefix + jax.tree_util.keystr(p), x) for p, x in leaves)
    return {name: np.asarray(x) for name, x in named if "kernel" not in name}


def short_run(name: str, layout_name: str) -> dict:
    """One seed of run ``name`` in layout ``layout_name``, in 64-bit floats: every episode record, the learner's
    metrics and some parameter leaves of the final state."""
    from train.build import make_train
    from train.config import load_config
    from train.trainer import seed_keys

    scenario, algo, overrides = CONFIGS[name]
    cfg = load_config(scenario, algo, json.loads(json.dumps(overrides)))
    with jax.enable_x64(True):
        with layout(layout_name):
            trainer = make_train(cfg)
        state, metrics = jax.jit(trainer.train)(seed_keys(cfg)[0])
    out = {f"episode_{k}": np.asarray(v) for k, v in metrics["episode"].items()}
    out.update({f"update_{k}": np.asarray(v) for k, v in metrics["update"].items()})
    agent = state.agent
    if hasattr(agent, "actors"):  # the MADDPG family
        out.update(_leaves(agent.actors, "actors"))
        out.update(_leaves(agent.critics, "critics"))
        out["lam"] = np.asarray(agent.lam)
    else:
        out.update(_leaves(agent.actor, "actor"))
        out.update(_leaves(agent.critic, "critic"))
        out["lagrange"] = np.asarray(agent.lagrange)
        out["obs_mean"] = np.asarray(agent.obs_stats.mean)
    return out


def all_outputs() -> dict:
    out = {f"config/{name}": np.asarray(json.dumps(CONFIGS[name])) for name in CONFIGS}
    for name in CONFIGS:
        for lay in LAYOUTS:
            out.update({f"{name}/{lay}/{k}": v for k, v in short_run(name, lay).items()})
    return out


if __name__ == "__main__":
    np.savez_compressed(REFERENCE, **all_outputs())
    print("wrote", REFERENCE, os.path.getsize(REFERENCE), "bytes")
