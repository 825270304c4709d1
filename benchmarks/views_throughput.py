"""Steps per second of each framework view next to the simulator's own, for the same scenario.

```
python benchmarks/views_throughput.py --scenario merge --steps 200 --num-envs 1024 \
    --out benchmarks/results/views_throughput.json
python benchmarks/views_throughput.py --scenario highway-fast-v0 --controlled-vehicles 2   # a traffic task
```

Pairs, each measured after a warm-up call (compilation excluded):

* host, one environment per call: the simulator's eager ``env.step`` (one compiled call and a
  device sync per step) vs the PettingZoo ``ParallelEnv`` and the Gymnasium ``Env`` (the same
  call plus the dict/numpy conversion and host copies); the difference per step is what the
  host views pay for transfers and conversion.
* device, one jitted ``lax.scan`` over N vmapped environments: ``envs_jax.rollout``'s
  ``AutoResetWrapper`` (a traffic task: the simulator's step with the reset written out,
  :func:`autoreset_step`) vs the JaxMARL view (in JaxMARL's ``LogWrapper``).
* host, N environments per call: a jitted ``vmap`` of the simulator's auto-reset step called
  once per step with numpy actions and results copied back vs the batched PettingZoo view and
  the Gymnasium ``VectorEnv`` (same pattern, plus the views' bookkeeping).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir))

import envs_jax  # noqa: E402
from envs_jax.views import (  # noqa: E402
    AgentSpec,
    BatchedPettingZooDrivingEnv,
    GymnasiumDrivingEnv,
    GymnasiumVectorDrivingEnv,
    JaxMARLDrivingEnv,
    PettingZooDrivingEnv,
    idle_policy,
)


def timed(fn, steps: int, repeats: int) -> float:
    """Best-of-``repeats`` seconds for ``fn()`` (which runs ``steps`` steps)."""
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def host_actions(env, rng, shape=()):
    if env.discrete:
        return rng.integers(0, env.num_actions, shape + (env.num_agents,)).astype(np.int32)
    return rng.uniform(-1, 1, shape + tuple(env.action_shape)).astype(np.float32)


class TaskAutoReset:
    """A traffic task's step with the auto-reset written out (JaxMARL's key split), the core side of the pairs;
    the two-agent scenarios use ``envs_jax.AutoResetWrapper``."""

    def __init__(self, env):
        self.env = env

    def reset(self, key):
        return self.env.reset(key)

    def step(self, key, state, action):
        key_step, key_reset = jax.random.split(key)
        obs, st, reward, cost, done, info = self.env.step(key_step, state, action)
        obs_re, st_re = self.env.reset(key_reset)
        st = jax.tree.map(lambda a, b: jnp.where(done, a, b), st_re, st)
        return jnp.where(done, obs_re, obs), st, reward, cost, done, info


def task_rollout(env, key, num_envs: int, num_steps: int):
    """``envs_jax.rollout`` for a traffic task: a scan of uniform random actions over vmapped auto-resetting envs."""
    wrapped, spec = TaskAutoReset(env), AgentSpec.of(env)
    _, st = jax.vmap(wrapped.reset)(jax.random.split(key, num_envs))

    def body(st, key):
        k_act, k_step = jax.random.split(key)
        if spec.discrete:
            action = jax.random.randint(k_act, (num_envs, spec.num_agents), 0, spec.num_actions)
        else:
            action = jax.random.uniform(k_act, (num_envs, spec.num_agents, spec.action_dim), minval=-1.0, maxval=1.0)
        _, st, reward, *_ = jax.vmap(wrapped.step)(jax.random.split(k_step, num_envs), st, action)
        return st, reward[:, 0]

    return jax.lax.scan(body, st, jax.random.split(jax.random.fold_in(key, 1), num_steps))[1]


def bench(name: str, steps: int, num_envs: int, batched_envs: int, repeats: int, overrides: dict | None = None) -> dict:
    env = envs_jax.make(name, **(overrides or {}))
    task = name in envs_jax.available_tasks()
    partner = idle_policy(env) if env.num_agents > 1 else None
    rng = np.random.default_rng(0)
    res = {}

    # ---- host, one environment per call
    acts = [host_actions(env, rng) for _ in range(steps)]

    def core_eager():
        obs, st = env.reset(jax.random.key(0))
        key = jax.random.key(1)
        for a in acts:
            key, k = jax.random.split(key)
            obs, st, r, c, done, info = env.step(k, st, a)
            jax.device_get((obs, r, c, done, info))  # what a host loop reads every step
            if bool(done):
                obs, st = env.reset(k)

    pz = PettingZooDrivingEnv(env)
    agents = pz.possible_agents

    def pettingzoo():
        pz.reset(seed=0)
        for a in acts:
            if not pz.agents:
                pz.reset()
            pz.step({ag: (int(a[i]) if env.discrete else a[i]) for i, ag in enumerate(agents) if ag in pz.agents})

    gym = GymnasiumDrivingEnv(env, partner_policy=partner)

    def gymnasium_env():
        gym.reset(seed=0)
        for a in acts:
            _, _, term, trunc, _ = gym.step(int(a[0]) if env.discrete else a[0])
            if term or trunc:
                gym.reset()

    for label, fn in [("core_eager_step", core_eager), ("pettingzoo_parallel_env", pettingzoo),
                      ("gymnasium_env", gymnasium_env)]:
        fn()  # warm-up (compiles)
        sec = timed(fn, steps, repeats)
        res[label] = {"steps_per_s": steps / sec, "us_per_step": 1e6 * sec / steps, "num_envs": 1}
    for label in ("pettingzoo_parallel_env", "gymnasium_env"):
        res[label]["host_overhead_us_per_step_vs_core_eager"] = res[label]["us_per_step"] - res["core_eager_step"][
            "us_per_step"]

    # ---- device, one jitted scan over N vmapped environments
    core_rollout = jax.jit(task_rollout if task else envs_jax.rollout, static_argnums=(0, 2, 3))
    view = JaxMARLDrivingEnv(env)
    from jaxmarl.wrappers.baselines import LogWrapper

    logged = LogWrapper(view)

    @jax.jit
    def jaxmarl_rollout(key):
        k_reset, k_run = jax.random.split(key)
        obs, st = jax.vmap(logged.reset)(jax.random.split(k_reset, num_envs))

        def body(st, key):
            k_act, k_step = jax.random.split(key)
            keys = jax.random.split(k_act, view.num_agents)
            actions = {a: jax.vmap(view.action_space(a).sample)(jax.random.split(keys[i], num_envs))
                       for i, a in enumerate(view.agents)}
            obs, st, rew, done, info = jax.vmap(logged.step)(jax.random.split(k_step, num_envs), st, actions)
            return st, rew["agent_0"]

        return jax.lax.scan(body, st, jax.random.split(k_run, steps))[1]

    for label, fn in [("core_rollout_scan", lambda: jax.block_until_ready(
            core_rollout(env, jax.random.key(0), num_envs, steps))),
                      ("jaxmarl_view_scan", lambda: jax.block_until_ready(jaxmarl_rollout(jax.random.key(0))))]:
        fn()
        sec = timed(fn, steps, repeats)
        res[label] = {"steps_per_s": steps * num_envs / sec, "num_envs": num_envs, "scan_steps": steps}

    # ---- host, N environments per call
    wrapped = TaskAutoReset(env) if task else envs_jax.AutoResetWrapper(env)
    vstep = jax.jit(jax.vmap(wrapped.step))
    n = batched_envs
    bacts = [host_actions(env, rng, (n,)) for _ in range(min(steps, 50))]
    bsteps = len(bacts)

    def core_batched():
        _, st = jax.vmap(wrapped.reset)(jax.random.split(jax.random.key(0), n))
        key = jax.random.key(1)
        for a in bacts:
            key, k = jax.random.split(key)
            obs, st, r, c, done, info = vstep(jax.random.split(k, n), st, jnp.asarray(a))
            jax.device_get((obs, r, c, done, info["terminated"], info["truncated"]))  # what a host loop reads

    bpz = BatchedPettingZooDrivingEnv(env, n)

    def pettingzoo_batched():
        bpz.reset(seed=0)
        for a in bacts:
            bpz.step({ag: a[:, i] for i, ag in enumerate(agents)})

    vec = GymnasiumVectorDrivingEnv(env, n, partner_policy=partner)

    def gymnasium_vector():
        vec.reset(seed=0)
        for a in bacts:
            vec.step(a[:, 0])

    for label, fn in [("core_vmapped_step_host_loop", core_batched), ("pettingzoo_batched", pettingzoo_batched),
                      ("gymnasium_vector_env", gymnasium_vector)]:
        fn()
        sec = timed(fn, bsteps, repeats)
        res[label] = {"steps_per_s": bsteps * n / sec, "calls_per_s": bsteps / sec, "num_envs": n}
    return res


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="merge",
                        choices=envs_jax.available_scenarios() + envs_jax.available_tasks())
    parser.add_argument("--controlled-vehicles", type=int, default=None, help="a traffic task's K (default: its own)")
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--num-envs", type=int, default=256, help="environments of the jitted scan pair")
    parser.add_argument("--batched-envs", type=int, default=1024, help="environments of the batched host views")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    overrides = {} if args.controlled_vehicles is None else {"controlled_vehicles": args.controlled_vehicles}
    res = bench(args.scenario, args.steps, args.num_envs, args.batched_envs, args.repeats, overrides)
    for label, r in res.items():
        extra = (f"  (+{r['host_overhead_us_per_step_vs_core_eager']:.0f} us/step vs core eager)"
                 if "host_overhead_us_per_step_vs_core_eager" in r else "")
        print(f"{label:32s} {r['steps_per_s']:12.0f} env steps/s  num_envs={r['num_envs']}{extra}")
    if args.out:
        out = {"scenario": args.scenario, "settings": vars(args), "results": res,
               "machine": {"platform": platform.platform(), "backend": jax.default_backend(),
                           "devices": [str(d) for d in jax.devices()], "cpu_count": os.cpu_count(),
                           "load_average": os.getloadavg()},
               "jax": jax.__version__}
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(out, f, indent=2)
        print("wrote", args.out)


if __name__ == "__main__":
    main()
