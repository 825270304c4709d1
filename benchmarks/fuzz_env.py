"""Fuzz the simulator with adversarial actions and count steps that produce a non-finite number.

Every scenario runs ``--envs`` auto-resetting environments inside one jitted ``lax.scan`` per chunk, with
actions drawn afresh for every agent and step:

* merge, roundabout (discrete meta-actions 0..4): half uniform in 0..4, half out of range (any int32,
  including INT32_MIN / INT32_MAX, -1 and 5);
* intersection, racetrack (continuous, [-1, 1]): each component one of uniform [-1, 1], uniform [-1e3, 1e3],
  NaN, +inf, -inf, +1e30, -1e30, the largest float, the smallest subnormal, with equal probability.

A step counts as bad when any floating-point number it produces is not finite: any field of the state it
returns (before the auto-reset), the observation, the reward or the cost. The counts, the rate and the run's
size are printed and written to ``benchmarks/results/fuzz_env.json``.

    python benchmarks/fuzz_env.py                          # 10^8 steps per scenario
    python benchmarks/fuzz_env.py --steps 1000000 --scenarios merge racetrack
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import envs_jax  # noqa: E402

SCENARIOS = ("merge", "roundabout", "intersection", "racetrack")
OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "fuzz_env.json")


def adversarial_actions(env):
    """``key -> action`` of ``env.action_shape``: a mix of valid and invalid actions (see the module doc)."""
    shape = env.action_shape
    if env.discrete:
        def act(key):
            k_kind, k_valid, k_any, k_edge = jax.random.split(key, 4)
            valid = jax.random.randint(k_valid, shape, 0, env.num_actions)
            anything = jax.random.bits(k_any, shape, jnp.uint32).astype(jnp.int32)  # any int32, wrapping
            edges = jnp.array([np.iinfo(np.int32).min, np.iinfo(np.int32).max, -1, 5], jnp.int32)
            edge = edges[jax.random.randint(k_edge, shape, 0, 4)]
            kind = jax.random.randint(k_kind, shape, 0, 4)  # 0, 1: valid; 2: any int32; 3: an edge value
            return jnp.where(kind < 2, valid, jnp.where(kind == 2, anything, edge))

        return act

    dtype = jnp.zeros(()).dtype  # float32, or float64 under x64
    fmax = float(jnp.finfo(dtype).max)
    tiny = float(jnp.finfo(dtype).smallest_subnormal)
    specials = jnp.array([jnp.nan, jnp.inf, -jnp.inf, 1e30, -1e30, fmax, tiny], dtype)

    def act(key):
        k_kind, k_in, k_out, k_sp = jax.random.split(key, 4)
        kind = jax.random.randint(k_kind, shape, 0, 2 + specials.size)
        inside = jax.random.uniform(k_in, shape, dtype, -1.0, 1.0)
        outside = jax.random.uniform(k_out, shape, dtype, -1e3, 1e3)
        special = specials[jnp.clip(kind - 2, 0, specials.size - 1)]
        return jnp.where(kind == 0, inside, jnp.where(kind == 1, outside, special))

    return act


def _not_finite(tree) -> jax.Array:
    """True if any floating-point leaf of ``tree`` holds a NaN or an infinity."""
    flags = [~jnp.all(jnp.isfinite(x)) for x in jax.tree.leaves(tree) if jnp.issubdtype(x.dtype, jnp.floating)]
    return jnp.any(jnp.stack(flags)) if flags else jnp.zeros((), bool)


def make_chunk(env, num_envs: int, num_steps: int):
    """Jitted ``(key, obs, state) -> (obs, state, counts)`` for ``num_steps`` steps of ``num_envs`` envs."""
    params = env.default_params
    act = adversarial_actions(env)

    def one_env(key, obs, state):
        k_act, k_step, k_reset = jax.random.split(key, 3)
        action = act(k_act)
        obs2, st2, reward, cost, done, _ = env.step(k_step, state, action, params)
        bad = jnp.stack([_not_finite(st2), _not_finite(obs2), _not_finite(reward), _not_finite(cost)])
        obs_r, st_r = env.reset(k_reset, params)
        st_next = jax.tree.map(lambda a, b: jnp.where(done, a, b), st_r, st2)
        obs_next = jnp.where(done, obs_r, obs2)
        # a non-finite state is not carried on (it would count every later step of that env as bad too)
        st_next = jax.tree.map(lambda a, b: jnp.where(bad[0], a, b), st_r, st_next)
        return obs_next, st_next, bad, done

    def chunk(key, obs, state):
        def body(carry, k):
            obs, state, counts = carry
            obs, state, bad, done = jax.vmap(one_env)(jax.random.split(k, num_envs), obs, state)
            counts = counts + jnp.concatenate([jnp.sum(bad, 0), jnp.sum(jnp.any(bad, 1))[None],
                                               jnp.sum(done)[None]]).astype(jnp.int32)
            return (obs, state, counts), None

        (obs, state, counts), _ = jax.lax.scan(body, (obs, state, jnp.zeros(6, jnp.int32)),
                                               jax.random.split(key, num_steps))
        return obs, state, counts

    return jax.jit(chunk, donate_argnums=(1, 2))


def fuzz(name, total_steps: int, num_envs: int, chunk_steps: int, seed: int) -> dict:
    """Counts for ``total_steps`` adversarial steps of scenario ``name`` (or of a given env)."""
    env = envs_jax.make(name) if isinstance(name, str) else name
    num_envs = min(num_envs, total_steps)
    chunk_steps = max(1, min(chunk_steps, total_steps // num_envs))
    n_chunks = math.ceil(total_steps / (num_envs * chunk_steps))
    run = make_chunk(env, num_envs, chunk_steps)
    key = jax.random.PRNGKey(seed)
    key, k0 = jax.random.split(key)
    obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(k0, num_envs), env.default_params)
    counts = np.zeros(6, np.int64)
    t0 = time.perf_counter()
    for i in range(n_chunks):
        obs, state, c = run(jax.random.fold_in(key, i), obs, state)
        counts += np.asarray(c, np.int64)
        if i == 0:
            t_first = time.perf_counter() - t0
    wall = time.perf_counter() - t0
    steps = n_chunks * num_envs * chunk_steps
    names = ("state", "observation", "reward", "cost")
    res = {"steps": steps, "num_envs": num_envs, "chunk_steps": chunk_steps, "episodes_ended": int(counts[5]),
           "bad_steps": int(counts[4]), "bad_rate": float(counts[4]) / steps,
           "bad_by_output": {n: int(counts[j]) for j, n in enumerate(names)},
           "seconds": wall, "first_chunk_s_with_compile": t_first,
           "steps_per_s": steps / max(wall - t_first, 1e-9) * (n_chunks - 1) / n_chunks if n_chunks > 1 else None,
           "actions": "discrete: 1/2 uniform 0..4, 1/4 any int32, 1/4 of {INT32_MIN, INT32_MAX, -1, 5}"
                      if env.discrete else "continuous: 1/9 each of U[-1,1], U[-1e3,1e3], NaN, +inf, -inf, "
                                           "+1e30, -1e30, float max, smallest subnormal"}
    return res


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=float, default=1e8, help="random steps per scenario (default 1e8)")
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    p.add_argument("--envs", type=int, default=4096, help="parallel environments (default 4096)")
    p.add_argument("--chunk-steps", type=int, default=128, help="policy steps per compiled call (default 128)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=OUT, help="JSON results file (default benchmarks/results/fuzz_env.json)")
    a = p.parse_args(argv)
    total = int(a.steps)
    if total < 1 or a.envs < 1 or a.chunk_steps < 1:
        p.error("--steps, --envs and --chunk-steps must be >= 1")
    out = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__,
                       "device": str(jax.devices()[0]), "x64": bool(jax.config.jax_enable_x64)},
           "command": " ".join(["python benchmarks/fuzz_env.py"] + (argv if argv is not None else sys.argv[1:])),
           "scenarios": {}}
    for name in a.scenarios:
        res = fuzz(name, total, a.envs, a.chunk_steps, a.seed)
        out["scenarios"][name] = res
        b = res["bad_by_output"]
        print(f"{name:<12} {res['steps']:>12,} steps  bad {res['bad_steps']:,} (rate {res['bad_rate']:.3g}; state "
              f"{b['state']}, obs {b['observation']}, reward {b['reward']}, cost {b['cost']})  "
              f"{res['episodes_ended']:,} episodes  {res['seconds']:.0f} s", flush=True)
        os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
        with open(a.out + ".tmp", "w") as f:  # after every scenario: a run cut short keeps what it measured
            json.dump(out, f, indent=2)
        os.replace(a.out + ".tmp", a.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
