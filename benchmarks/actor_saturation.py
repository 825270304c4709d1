"""Is a MADDPG-family run's actor stuck in tanh saturation?

For each seed of a saved run (``cs-maddpg``, ``s-maddpg``, ``c-maddpg``, ``maddpg``) it evaluates the greedy
decision at ``--starts`` reset states of the scenario and prints, per agent, the actor's output before
``max_action * tanh`` (the largest |x| and the mean tanh'(x)). An actor whose |x| is far above 1 at the start
states passes almost no gradient back (tanh' ~ 0) and no longer learns: the racetrack seed that crashes from
the start of every episode (README, "Racetrack") is one.

    python benchmarks/actor_saturation.py RUN_DIR [--step N] [--starts 16]
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

SATURATED = 3.0  # |x| above which tanh'(x) < 0.01


def saturation(run_dir: str, step: int | None = None, starts: int = 16) -> list[dict]:
    """Per seed: ``max_abs`` and ``mean_dtanh`` ``[leader, follower]`` over the reset states, and ``saturated``."""
    import jax
    import numpy as np

    from train.config import read_run_config
    from train.restore import restore_run

    if starts < 1:
        raise ValueError(f"--starts must be at least 1, got {starts}")
    algo = read_run_config(run_dir)["algo"]
    if algo not in ("cs-maddpg", "s-maddpg", "c-maddpg", "maddpg"):
        raise ValueError(f"{run_dir} is a '{algo}' run; this check is for the MADDPG family "
                         "(cs-maddpg, s-maddpg, c-maddpg, maddpg), whose actors end in tanh")
    _, trainer, state, meta = restore_run(run_dir, step)
    env, params = trainer.env, trainer.env.default_params
    obs, _ = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(jax.random.PRNGKey(0), starts), params)
    pre = jax.vmap(trainer.agent.greedy_preactivations, in_axes=(0, None))(state.agent.actors, obs)
    z = np.asarray(pre, np.float64)  # [S, starts, 2, action_dim]
    rows = []
    for s in range(z.shape[0]):
        zs = z[s].reshape(starts, 2, -1)
        max_abs = np.abs(zs).max(axis=(0, 2))
        mean_dtanh = (1.0 - np.tanh(zs) ** 2).mean(axis=(0, 2))
        rows.append({"seed": s, "env_steps": meta.get("env_steps"), "max_abs": max_abs.tolist(),
                     "mean_dtanh": mean_dtanh.tolist(), "saturated": bool(np.any(max_abs > SATURATED))})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("run_dir")
    p.add_argument("--step", type=int, default=None, help="checkpoint (env steps; default the newest)")
    p.add_argument("--starts", type=int, default=16, help="reset states to evaluate at (default 16)")
    args = p.parse_args(argv)
    try:
        rows = saturation(args.run_dir, args.step, args.starts)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{args.run_dir} at {rows[0]['env_steps']} env steps; actor output before tanh at {args.starts} start "
          f"states (saturated: |x| > {SATURATED:g})")
    print("seed | leader max |x| | leader mean tanh' | follower max |x| | follower mean tanh' |")
    for r in rows:
        flag = "  SATURATED" if r["saturated"] else ""
        print(f"{r['seed']:4d} | {r['max_abs'][0]:14.3f} | {r['mean_dtanh'][0]:17.2e} | {r['max_abs'][1]:16.3f} | "
              f"{r['mean_dtanh'][1]:19.2e} |{flag}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
