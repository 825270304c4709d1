"""Many traffic episodes at once on every CPU core: one pure-JAX roll-out, its environments split over the cores.

```
python examples/rollout_all_cores.py --task highway-v0 --num-envs 256 --steps 40
python examples/rollout_all_cores.py --task merge-v0 --controlled-vehicles 3 --devices 1
```

XLA:CPU runs a batched program's small kernels on one thread, so a ``vmap`` over environments keeps one core
busy. Making every core a JAX device (``jax_num_cpu_devices``) and running each device's share of the
environments as its own program (``shard_map``, through ``train.parallel.seed_parallel``, which splits the
training runs' seeds the same way) uses them all, as EnvPool runs a thread per core (docs/performance.md). Each
environment draws from its own key, so the per-environment results do not depend on how many devices share the
work.
"""

from __future__ import annotations

import argparse
import os
import time


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--task", default="highway-v0", help="an envs_jax traffic task (envs_jax.available_tasks())")
    parser.add_argument("--controlled-vehicles", type=int, default=None,
                        help="controlled vehicles K (default: the task's)")
    parser.add_argument("--num-envs", type=int, default=64, help="parallel environments (all devices together)")
    parser.add_argument("--steps", type=int, default=40, help="policy steps per environment")
    parser.add_argument("--devices", type=int, default=os.cpu_count() or 1,
                        help="CPU devices to split the environments over (default: one per core)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    for name in ("num_envs", "steps", "devices"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(args, name)}")
    return args


def main(argv=None) -> dict:
    args = parse_args(argv)
    import jax

    try:  # one JAX device per core: only possible before JAX has run anything in this process
        jax.config.update("jax_num_cpu_devices", args.devices)
    except RuntimeError:
        print(f"JAX was already running: using its {len(jax.devices())} device(s)")
    import numpy as np

    import envs_jax
    from envs_jax.traffic_autoreset import TrafficAutoResetWrapper
    from envs_jax.wrappers import random_actions
    from train.parallel import seed_parallel, seed_sharding

    if args.task not in envs_jax.available_tasks():
        raise ValueError(f"--task {args.task!r} is not a traffic task; choose one of {envs_jax.available_tasks()}")
    given = {} if args.controlled_vehicles is None else {"controlled_vehicles": args.controlled_vehicles}
    env = envs_jax.make(args.task, **given)
    wrapped = TrafficAutoResetWrapper(env)
    params = env.default_params
    policy = random_actions(env)

    def one_env(key):
        """One environment's roll-out: returns per agent, costs, episodes ended and crashed."""
        key, key_reset = jax.random.split(key)
        obs, state = wrapped.reset(key_reset, params)

        def body(carry, _):
            obs, state, key = carry
            key, key_act, key_step = jax.random.split(key, 3)
            obs, state, reward, cost, _, info = wrapped.step(key_step, state, policy(key_act, obs), params)
            ended = info["returned_episode"]
            return (obs, state, key), (reward, cost, ended, ended & info["episode_crash"])

        _, (reward, cost, ended, crashed) = jax.lax.scan(body, (obs, state, key), None, length=args.steps)
        return reward.sum(0), cost.sum(0), ended.sum(), crashed.sum()

    # jit(vmap(one_env)) with the environments split over the devices, each device's share its own program: the
    # helper the training runs split their seeds with (as many devices as divide num_envs)
    run = seed_parallel(one_env, args.num_envs)
    sharding = seed_sharding(args.num_envs)
    devices = 1 if sharding is None else sharding.mesh.size
    keys = jax.random.split(jax.random.key(args.seed), args.num_envs)
    t0 = time.perf_counter()
    jax.block_until_ready(run(keys))
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    returns, costs, episodes, crashes = jax.block_until_ready(run(keys))
    seconds = time.perf_counter() - t0
    steps_per_s = args.num_envs * args.steps / seconds
    print(f"{args.task}: {args.num_envs} envs x {args.steps} steps on {devices} device(s) in {seconds:.2f} s "
          f"({steps_per_s:,.0f} env steps/s; compiling and the first run took {compile_s:.1f} s)")
    print(f"  {int(episodes.sum())} episodes ended, {int(crashes.sum())} of them with a crash; return per agent "
          f"and step {float(returns.mean()) / args.steps:.3f}, cost per agent and step "
          f"{float(costs.mean()) / args.steps:.3f}")
    return {"devices": devices, "steps_per_s": steps_per_s, "returns": np.asarray(returns),
            "costs": np.asarray(costs), "episodes": np.asarray(episodes), "crashes": np.asarray(crashes)}


if __name__ == "__main__":
    main()
