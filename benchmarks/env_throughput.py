"""Environment steps per second: envs_jax (1..65,536 parallel envs) vs highway-env, side by side.

Each JAX measurement runs ``N`` auto-resetting environments with uniform random
actions for ``T`` policy steps inside one jitted ``lax.scan``; compilation is timed
apart and the figure is the median over repeats. highway-env steps the same
scenario (the authors' configuration, ``tests/highway_oracle.py``) with random
actions in this process, in between. Ratios are JAX / highway-env.

    python benchmarks/env_throughput.py                   # full curve, all scenarios
    python benchmarks/env_throughput.py --quick           # a smaller curve
    python benchmarks/env_throughput.py --scenarios merge --envs 1 4096
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import envs_jax  # noqa: E402
from envs_jax.wrappers import AutoResetWrapper, random_actions  # noqa: E402


def jax_runner(env, num_envs: int, num_steps: int, wrapper=AutoResetWrapper, actions=random_actions):
    """Jitted ``key -> finished episodes``: ``num_steps`` auto-reset steps of ``num_envs`` envs, random actions.
    ``wrapper``/``actions``: the auto-reset wrapper and random policy of the package ``env`` comes from."""
    wrapped = wrapper(env)
    params = env.default_params
    policy = actions(env)

    def run(key):
        key, key_reset = jax.random.split(key)
        obs, state = jax.vmap(wrapped.reset, in_axes=(0, None))(jax.random.split(key_reset, num_envs), params)

        def body(carry, _):
            obs, state, key, episodes = carry
            key, key_act, key_step = jax.random.split(key, 3)
            action = jax.vmap(policy)(jax.random.split(key_act, num_envs), obs)
            obs, state, _, _, done, _ = jax.vmap(wrapped.step, in_axes=(0, 0, 0, None))(
                jax.random.split(key_step, num_envs), state, action, params)
            return (obs, state, key, episodes + done.sum()), None

        (_, _, _, episodes), _ = jax.lax.scan(body, (obs, state, key, jnp.zeros((), jnp.int32)), None,
                                              length=num_steps)
        return episodes

    return jax.jit(run)


def measure_jax(env, num_envs: int, num_steps: int, repeats: int):
    run = jax_runner(env, num_envs, num_steps)
    t0 = time.perf_counter()
    run(jax.random.key(0)).block_until_ready()
    first = time.perf_counter() - t0
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        run(jax.random.key(r + 1)).block_until_ready()
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    return {"num_envs": num_envs, "num_steps": num_steps, "seconds": med,
            "steps_per_s": num_envs * num_steps / med, "compile_s": max(first - med, 0.0)}


def measure_highway(name: str, seconds: float):
    from tests.highway_oracle import make_oracle_env

    env = make_oracle_env(name)
    rng = np.random.default_rng(0)
    discrete = env.config["action"]["action_config"]["type"] == "DiscreteMetaAction"
    env.reset(seed=0)
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        action = tuple(int(a) for a in rng.integers(0, 5, 2)) if discrete else \
            tuple(rng.uniform(-1, 1, (2, 1)).astype(np.float32))
        _, _, terminated, _, _ = env.step(action)
        steps += 1
        if np.all(terminated):
            env.reset()
    return steps / (time.perf_counter() - t0)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="+", default=envs_jax.available_scenarios(), help="scenarios to measure")
    parser.add_argument("--envs", nargs="+", type=int, default=[1, 16, 256, 4096, 65536],
                        help="numbers of parallel environments")
    parser.add_argument("--env-steps", type=int, default=1 << 19,
                        help="environment steps per JAX measurement (T = max(10, this / N))")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per point (median)")
    parser.add_argument("--highway-seconds", type=float, default=10.0, help="time highway-env is stepped")
    parser.add_argument("--quick", action="store_true", help="envs 1, 256, 4096 and fewer steps")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "env_throughput.json"))
    args = parser.parse_args(argv)
    if args.quick:
        args.envs, args.env_steps, args.highway_seconds = [1, 256, 4096], 1 << 16, 5.0

    results = {"machine": {"platform": platform.platform(), "processor": platform.processor(),
                           "cpus": os.cpu_count(), "jax": jax.__version__,
                           "device": str(jax.devices()[0])}, "scenarios": {}}
    print(f"device: {jax.devices()[0]}, {os.cpu_count()} CPUs, jax {jax.__version__}")
    for name in args.scenarios:
        env = envs_jax.make(name)
        hw = measure_highway(name, args.highway_seconds)
        rows = []
        for n in args.envs:
            t = max(10, args.env_steps // n)
            row = measure_jax(env, n, t, args.repeats)
            row["ratio"] = row["steps_per_s"] / hw
            rows.append(row)
        results["scenarios"][name] = {"highway_env_steps_per_s": hw, "jax": rows}
        print(f"\n{name}: highway-env {hw:,.0f} steps/s")
        print(f"{'envs':>8} {'steps':>6} {'steps/s':>14} {'x highway-env':>14} {'compile s':>10}")
        for r in rows:
            print(f"{r['num_envs']:>8} {r['num_steps']:>6} {r['steps_per_s']:>14,.0f} {r['ratio']:>14,.0f} "
                  f"{r['compile_s']:>10.1f}")
        os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
        with open(args.out, "w") as f:  # after every scenario: a run cut short keeps what it measured
            json.dump(results, f, indent=2)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
