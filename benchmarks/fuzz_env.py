"""Fuzz the simulator with adversarial actions and count steps that produce a non-finite number.

Every scenario runs ``--envs`` auto-resetting environments inside one jitted ``lax.scan`` per segment of
``--segment-steps`` steps (each segment starts from fresh resets), with actions drawn afresh for every agent
and step:

* merge, roundabout (discrete meta-actions 0..4): half uniform in 0..4, half out of range (any int32,
  including INT32_MIN / INT32_MAX, -1 and 5);
* intersection, racetrack (continuous, [-1, 1]): each component one of uniform [-1, 1], uniform [-1e3, 1e3],
  NaN, +inf, -inf, +1e30, -1e30, the largest float, the smallest subnormal, with equal probability.

A step counts as bad when any floating-point number it produces is not finite: any field of the state it
returns (before the auto-reset), the observation, the reward or the cost. The counts, the rate and the run's
size are printed and written to ``benchmarks/results/fuzz_env.json`` (also during a scenario, at most once a
minute, marked ``"complete": false``).

    python benchmarks/fuzz_env.py                          # 10^8 steps per scenario
    python benchmarks/fuzz_env.py --steps 1000000 --scenarios merge racetrack
    python benchmarks/fuzz_env.py --max-seconds 600      # as many steps per scenario as fit in ~10 minutes
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


def make_segment(env, num_envs: int, num_steps: int):
    """Jitted ``key -> counts[6]``: ``num_envs`` freshly reset envs run ``num_steps`` adversarial steps.

    Counts: steps with a non-finite state, observation, reward, cost; steps with any of them; episodes ended.
    The envs are reset inside the compiled call, so no state is held between calls (a run can stop after any
    segment); an episode still running at the end of a segment is cut short there (``docs/reliability.md``).
    """
    params = env.default_params
    act = adversarial_actions(env)

    def one_env(key, obs, state):
        k_act, k_step, k_reset = jax.random.split(key, 3)
        action = act(k_act)
        obs2, st2, reward, cost, done, _ = env.step(k_step, state, action, params)
        bad = jnp.stack([_not_finite(st2), _not_finite(obs2), _not_finite(reward), _not_finite(cost)])
        obs_r, st_r = env.reset(k_reset, params)
        # a non-finite state is not carried on either (it would count every later step of that env as bad too)
        fresh = done | bad[0]
        st_next = jax.tree.map(lambda a, b: jnp.where(fresh, a, b), st_r, st2)
        return jnp.where(fresh, obs_r, obs2), st_next, bad, done

    def segment(key):
        key_reset, key_steps = jax.random.split(key)
        obs, state = jax.vmap(env.reset, in_axes=(0, None))(jax.random.split(key_reset, num_envs), params)

        def body(carry, k):
            obs, state, counts = carry
            obs, state, bad, done = jax.vmap(one_env)(jax.random.split(k, num_envs), obs, state)
            counts = counts + jnp.concatenate([jnp.sum(bad, 0), jnp.sum(jnp.any(bad, 1))[None],
                                               jnp.sum(done)[None]]).astype(jnp.int32)
            return (obs, state, counts), None

        (_, _, counts), _ = jax.lax.scan(body, (obs, state, jnp.zeros(6, jnp.int32)),
                                         jax.random.split(key_steps, num_steps))
        return counts

    return jax.jit(segment)


def fuzz(name, total_steps: int, num_envs: int, segment_steps: int, seed: int, max_seconds: float | None = None,
         progress=None) -> dict:
    """Counts for ``total_steps`` adversarial steps of scenario ``name`` (or of a given env), in segments of
    ``num_envs`` x ``segment_steps`` steps; stops after the segment that passes ``max_seconds`` (if given).
    ``progress(result)`` is called with the counts so far after every segment."""
    env = envs_jax.make(name) if isinstance(name, str) else name
    num_envs = min(num_envs, total_steps)
    segment_steps = max(1, min(segment_steps, total_steps // num_envs))
    n_segments = math.ceil(total_steps / (num_envs * segment_steps))
    run = make_segment(env, num_envs, segment_steps)
    key = jax.random.PRNGKey(seed)
    counts = np.zeros(6, np.int64)
    t0, c0 = time.perf_counter(), time.process_time()
    t_first = 0.0
    done = 0
    res = {}
    for i in range(n_segments):
        counts += np.asarray(run(jax.random.fold_in(key, i)), np.int64)
        done = i + 1
        wall = time.perf_counter() - t0
        if i == 0:
            t_first = wall
        res = _result(env, counts, done * num_envs * segment_steps, num_envs, segment_steps, wall, t_first,
                      time.process_time() - c0, done == n_segments)
        if progress is not None:
            progress(res)
        if max_seconds is not None and wall >= max_seconds:
            break
    return res


def _result(env, counts, steps, num_envs, segment_steps, wall, t_first, cpu, complete) -> dict:
    """The JSON record of one scenario's counts so far."""
    names = ("state", "observation", "reward", "cost")
    later = steps - num_envs * segment_steps  # steps after the first segment, which includes compilation
    return {"steps": steps, "complete": complete, "num_envs": num_envs, "segment_steps": segment_steps,
            "episodes_ended": int(counts[5]), "bad_steps": int(counts[4]), "bad_rate": float(counts[4]) / steps,
            "bad_by_output": {n: int(counts[j]) for j, n in enumerate(names)},
            "seconds": wall, "cpu_seconds": cpu, "first_segment_s_with_compile": t_first,
            "steps_per_s": later / (wall - t_first) if later > 0 else None,
            "load_avg_1min": os.getloadavg()[0],
            "actions": "discrete: 1/2 uniform 0..4, 1/4 any int32, 1/4 of {INT32_MIN, INT32_MAX, -1, 5}"
                       if env.discrete else "continuous: 1/9 each of U[-1,1], U[-1e3,1e3], NaN, +inf, -inf, "
                                            "+1e30, -1e30, float max, smallest subnormal"}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=float, default=1e8, help="random steps per scenario (default 1e8)")
    p.add_argument("--scenarios", nargs="+", default=list(SCENARIOS), choices=SCENARIOS)
    p.add_argument("--envs", type=int, default=4096, help="parallel environments (default 4096)")
    p.add_argument("--segment-steps", type=int, default=1024,
                   help="policy steps per compiled call, from fresh resets (default 1024)")
    p.add_argument("--max-seconds", type=float, default=None,
                   help="per scenario: stop after the segment that passes this many seconds (default: no limit)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default=OUT, help="JSON results file (default benchmarks/results/fuzz_env.json)")
    a = p.parse_args(argv)
    total = int(a.steps)
    if total < 1 or a.envs < 1 or a.segment_steps < 1:
        p.error("--steps, --envs and --segment-steps must be >= 1")
    if a.max_seconds is not None and not a.max_seconds > 0:
        p.error("--max-seconds must be > 0")
    out = {"machine": {"platform": platform.platform(), "cpus": os.cpu_count(), "jax": jax.__version__,
                       "device": str(jax.devices()[0]), "x64": bool(jax.config.jax_enable_x64)},
           "command": " ".join(["python benchmarks/fuzz_env.py"] + (argv if argv is not None else sys.argv[1:])),
           "scenarios": {}}
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    last_write = [0.0]

    def write(name, res, force=False):
        # rewritten during a scenario too (at most once a minute): a run cut short keeps what it counted
        out["scenarios"][name] = res
        if force or time.monotonic() - last_write[0] >= 60:
            with open(a.out + ".tmp", "w") as f:
                json.dump(out, f, indent=2)
            os.replace(a.out + ".tmp", a.out)
            last_write[0] = time.monotonic()

    for name in a.scenarios:
        res = fuzz(name, total, a.envs, a.segment_steps, a.seed, a.max_seconds, lambda r, name=name: write(name, r))
        write(name, res, force=True)
        b = res["bad_by_output"]
        rate = f"{res['steps_per_s']:,.0f} steps/s" if res["steps_per_s"] else "rate n/a (one segment)"
        print(f"{name:<12} {res['steps']:>12,} steps  bad {res['bad_steps']:,} (rate {res['bad_rate']:.3g}; state "
              f"{b['state']}, obs {b['observation']}, reward {b['reward']}, cost {b['cost']})  "
              f"{res['episodes_ended']:,} episodes  {res['seconds']:.0f} s  {rate}  load {res['load_avg_1min']:.1f}",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
