"""Environment steps per second: envs_jax vs highway-env, EnvPool and HighJax, side by side in one run.

Each JAX measurement runs ``N`` auto-resetting environments with uniform random
actions for ``T`` policy steps inside one jitted ``lax.scan``, the environments split
over one JAX CPU device per core (``--devices``; EnvPool runs a thread per core);
compilation is timed apart and the figure is the median over repeats. Two groups:

* the authors' two-agent scenarios (1..65,536 parallel envs), next to highway-env
  stepping the same scenario (``tests/highway_oracle.py``) in this process;
* highway-env's own tasks (``TASKS``; each one that ``envs_jax.make`` knows, the
  others skipped with a note), next to highway-env (``gymnasium.make(task)``),
  EnvPool's C++ port (threads = cores) and, on ``highway-v0``, HighJax
  (``benchmarks/baseline_sims.py``), after checking that they run the same task
  (vehicles, frequencies, duration, observation and action shapes).

Ratios are envs_jax / the other simulator (best figure of each). ``--baseline``
prints an earlier JSON's figures beside the new ones; the machine's load average
is recorded with every figure.

    python benchmarks/env_throughput.py                   # full curve, all scenarios and tasks
    python benchmarks/env_throughput.py --quick           # a smaller curve
    python benchmarks/env_throughput.py --scenarios merge --envs 1 4096 --tasks
    python benchmarks/env_throughput.py --scenarios --tasks highway-v0 --out /tmp/highway.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

import baseline_sims  # noqa: E402
import envs_jax  # noqa: E402
from envs_jax.sparse import reset_where  # noqa: E402
from envs_jax.wrappers import AutoResetWrapper, random_actions  # noqa: E402
from train.parallel import seed_parallel  # noqa: E402


def jax_runner(env, num_envs: int, num_steps: int, wrapper=AutoResetWrapper, actions=random_actions,
               devices: int = 1):
    """Jitted ``key -> finished episodes``: ``num_steps`` auto-reset steps of ``num_envs`` envs, random actions.
    ``wrapper``/``actions``: the auto-reset wrapper and random policy of the package ``env`` comes from.
    ``devices``: the environments are split over this many JAX devices (as many as divide ``num_envs``), each
    running its share as an independent program; on the CPU, with one device per core, that is how a JAX program
    uses every core, as EnvPool uses one thread per core."""
    d = math.gcd(num_envs, max(1, min(devices, len(jax.devices()))))
    local = _rollout(wrapper(env), env.default_params, actions(env), num_envs // d, num_steps)
    if d == 1:
        return jax.jit(local)
    # one roll-out of num_envs / d environments per device, as the training runs split their seeds
    per_device = seed_parallel(local, d, sequential=True)
    return jax.jit(lambda key: per_device(jax.random.split(key, d)).sum())


def _rollout(wrapped, params, policy, num_envs: int, num_steps: int):
    """``key -> finished episodes`` of ``num_envs`` auto-resetting envs over ``num_steps`` steps (not jitted)."""

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

    return run


def measure_jax(env, num_envs: int, num_steps: int, repeats: int, wrapper=AutoResetWrapper, actions=random_actions,
                devices: int = 1):
    run = jax_runner(env, num_envs, num_steps, wrapper, actions, devices)
    t0 = time.perf_counter()
    run(jax.random.key(0)).block_until_ready()
    first = time.perf_counter() - t0
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        run(jax.random.key(r + 1)).block_until_ready()
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    return {"num_envs": num_envs, "num_steps": num_steps, "devices": math.gcd(num_envs, devices), "seconds": med,
            "steps_per_s": num_envs * num_steps / med, "compile_s": max(first - med, 0.0), "load": load()}


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



# highway-env's own tasks, measured wherever envs_jax.make knows them
TASKS = ["highway-v0", "highway-fast-v0", "merge-v0", "roundabout-v0", "racetrack-v0", "intersection-v0",
         "intersection-v1", "intersection-multi-agent-v0"]
# what must agree for two simulators to run the same task
SAME_TASK_KEYS = ("vehicles", "controlled", "simulation_frequency", "policy_frequency", "duration", "obs_shape",
                  "actions", "action_shape")


def load() -> float:
    """The machine's 1-minute load average."""
    return os.getloadavg()[0]


class TaskAutoReset:
    """Resets a traffic task's environment when its episode ends (the rest of ``AutoResetWrapper``, whose
    episode statistics are the two-agent scenarios')."""

    def __init__(self, env):
        self.env = env

    def __getattr__(self, name):
        return getattr(self.env, name)

    def reset(self, key, params=None):
        return self.env.reset(key, params)

    def step(self, key, state, action, params=None):
        key_step, key_reset = jax.random.split(key)
        obs, st, reward, cost, done, info = self.env.step(key_step, state, action, params)
        obs_reset, st_reset = reset_where(self.env.reset, done, key_reset, params)  # as TrafficAutoResetWrapper
        st = jax.tree_util.tree_map(lambda a, b: jnp.where(done, a, b), st_reset, st)
        return jnp.where(done, obs_reset, obs), st, reward, cost, done, info


def describe_jax(env) -> dict:
    """The task as envs_jax runs it (same keys as ``baseline_sims.describe_*``)."""
    obs, state = env.reset(jax.random.key(0), env.default_params)
    out = {"vehicles": int(np.sum(state.alive)) if hasattr(state, "alive") else None,
           "controlled": int(getattr(env, "num_agents", 1)),
           "simulation_frequency": int(env.simulation_frequency), "policy_frequency": int(env.policy_frequency),
           "duration": float(env.default_params.duration), "obs_shape": list(np.shape(obs))}
    if env.discrete:
        out["actions"] = int(env.num_actions)
    else:
        out["action_shape"] = list(env.action_shape)
    if out["controlled"] == 1:  # one agent: drop the agent axis, as single-agent simulators do
        out["obs_shape"] = out["obs_shape"][1:] if out["obs_shape"][:1] == [1] else out["obs_shape"]
        if "action_shape" in out and out["action_shape"][:1] == [1] and len(out["action_shape"]) > 1:
            out["action_shape"] = out["action_shape"][1:]
    return out


def differences(ours: dict, theirs: dict) -> list[str]:
    """The keys of ``SAME_TASK_KEYS`` on which two task descriptions disagree, as readable lines."""
    out = []
    for key in SAME_TASK_KEYS:
        a, b = ours.get(key), theirs.get(key)
        if a is None and b is None:
            continue
        if key == "duration" and a is not None and b is not None and float(a) == float(b):
            continue
        if a != b:
            out.append(f"{key}: envs_jax {a}, theirs {b}")
    return out


def measure_task(name: str, args) -> dict:
    """One traffic task: envs_jax, highway-env, EnvPool and HighJax side by side (whichever are available)."""
    env = envs_jax.make(name)
    ours = describe_jax(env)
    result = {"task": ours, "load_start": load()}
    print(f"\n{name}: envs_jax {ours}")

    hw_desc = baseline_sims.describe_highway_env(name)
    result["highway_env"] = {"task": hw_desc, "differences": differences(ours, hw_desc),
                             **baseline_sims.measure_highway_env(name, args.highway_seconds)}
    result["highway_env"]["load"] = load()

    ep_ids, ep_note = baseline_sims.envpool_tasks()
    if name in ep_ids:
        ep_desc = baseline_sims.describe_envpool(name)
        rows = [baseline_sims.measure_envpool(name, n, b, args.envpool_seconds) | {"load": load()}
                for n, b in args.envpool_batches]
        result["envpool"] = {"version": ep_note, "task": ep_desc, "differences": differences(ours, ep_desc),
                             "rows": rows}
    else:
        result["envpool"] = {"note": f"{ep_note}: no task {name}" if ep_ids else ep_note}
        print(f"  EnvPool skipped: {result['envpool']['note']}")

    hj, hj_note = baseline_sims.highjax_env(name)
    if hj is not None:
        adapter = baseline_sims.HighJaxAdapter(*hj)
        hj_desc = baseline_sims.describe_highjax(*hj)
        rows = [measure_jax(adapter, n, max(args.task_min_steps, args.task_env_steps // n), args.repeats,
                            wrapper=lambda e: e, devices=args.devices) for n in args.task_envs]
        result["highjax"] = {"version": hj_note, "task": hj_desc, "differences": differences(ours, hj_desc),
                             "rows": rows}
    elif name in baseline_sims.HIGHJAX_TASKS:
        result["highjax"] = {"note": hj_note}
        print(f"  HighJax skipped: {hj_note}")

    result["jax"] = [measure_jax(env, n, max(args.task_min_steps, args.task_env_steps // n), args.repeats,
                                 wrapper=TaskAutoReset, devices=args.devices) for n in args.task_envs]
    best = max(r["steps_per_s"] for r in result["jax"])
    ratios = {"highway_env": best / result["highway_env"]["steps_per_s"]}
    for other in ("envpool", "highjax"):
        if "rows" in result.get(other, {}):
            ratios[other] = best / max(r["steps_per_s"] for r in result[other]["rows"])
    result["ratios"] = ratios
    result["load_end"] = load()
    print_task(name, result)
    return result


def print_task(name: str, result: dict) -> None:
    print(f"{name} (load {result['load_start']:.1f} -> {result['load_end']:.1f})")
    for other in ("highway_env", "envpool", "highjax"):
        diff = result.get(other, {}).get("differences")
        if diff:
            print(f"  {other} differs from envs_jax: {'; '.join(diff)}")
    print(f"  highway-env: {result['highway_env']['steps_per_s']:,.1f} steps/s")
    if "rows" in result["envpool"]:
        for r in result["envpool"]["rows"]:
            print(f"  EnvPool {r['num_envs']:>4} envs, batch {r['batch_size']:>4}, {r['num_threads']} threads: "
                  f"{r['steps_per_s']:>12,.0f} steps/s")
    for r in result.get("highjax", {}).get("rows", []):
        print(f"  HighJax {r['num_envs']:>6} envs x {r['num_steps']:>4} steps: {r['steps_per_s']:>12,.0f} steps/s "
              f"(compile {r['compile_s']:.1f} s)")
    for r in result["jax"]:
        print(f"  envs_jax {r['num_envs']:>5} envs x {r['num_steps']:>4} steps: {r['steps_per_s']:>12,.0f} steps/s "
              f"(compile {r['compile_s']:.1f} s)")
    labels = {"highway_env": "highway-env", "envpool": "EnvPool", "highjax": "HighJax"}
    print("  " + ", ".join(f"envs_jax / {labels[k]} = {v:,.2f}x" for k, v in result["ratios"].items()))


def print_scenario(name: str, entry: dict, baseline: dict | None) -> None:
    hw = entry["highway_env_steps_per_s"]
    print(f"\n{name}: highway-env {hw:,.0f} steps/s (load {entry['load_start']:.1f} -> {entry['load_end']:.1f})")
    base_rows = {}
    if baseline is not None and name in baseline.get("scenarios", {}):
        base_rows = {r["num_envs"]: r["steps_per_s"] for r in baseline["scenarios"][name]["jax"]}
        print(f"  baseline highway-env {baseline['scenarios'][name]['highway_env_steps_per_s']:,.0f} steps/s")
    extra = f" {'baseline':>12} {'new/base':>9}" if base_rows else ""
    print(f"{'envs':>8} {'steps':>6} {'steps/s':>14} {'x highway-env':>14} {'compile s':>10}{extra}")
    for r in entry["jax"]:
        line = (f"{r['num_envs']:>8} {r['num_steps']:>6} {r['steps_per_s']:>14,.0f} {r['ratio']:>14,.0f} "
                f"{r['compile_s']:>10.1f}")
        if r["num_envs"] in base_rows:
            b = base_rows[r["num_envs"]]
            r["baseline_steps_per_s"] = b
            line += f" {b:>12,.0f} {r['steps_per_s'] / b:>9.2f}"
        print(line)


def _batches(text: str) -> tuple[int, int]:
    num_envs, _, batch = text.partition(":")
    return int(num_envs), int(batch or num_envs)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="*", default=envs_jax.available_scenarios(),
                        help="two-agent scenarios to measure (none: skip them)")
    parser.add_argument("--envs", nargs="+", type=int, default=[1, 16, 256, 4096, 65536],
                        help="numbers of parallel environments (scenarios)")
    parser.add_argument("--env-steps", type=int, default=1 << 19,
                        help="environment steps per JAX measurement of a scenario (T = max(10, this / N))")
    parser.add_argument("--tasks", nargs="*", default=TASKS,
                        help="highway-env tasks to measure, those envs_jax.make knows (none: skip them)")
    parser.add_argument("--task-envs", nargs="+", type=int, default=[1, 16, 256],
                        help="numbers of parallel environments (tasks, envs_jax and HighJax)")
    parser.add_argument("--task-env-steps", type=int, default=1024,
                        help="environment steps per JAX measurement of a task (T = max(--task-min-steps, this / N))")
    parser.add_argument("--task-min-steps", type=int, default=4, help="least policy steps T per task measurement")
    parser.add_argument("--envpool-batches", nargs="+", type=_batches, default=[(2, 2), (8, 8), (32, 32), (32, 16)],
                        help="EnvPool configurations NUM_ENVS[:BATCH] (BATCH < NUM_ENVS: asynchronous)")
    parser.add_argument("--envpool-seconds", type=float, default=6.0, help="time EnvPool is stepped per configuration")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per point (median)")
    parser.add_argument("--highway-seconds", type=float, default=10.0, help="time highway-env is stepped")
    parser.add_argument("--baseline", default=None,
                        help="an earlier JSON of this script, printed beside the new figures")
    parser.add_argument("--quick", action="store_true", help="envs 1, 256, 4096 and fewer steps")
    parser.add_argument("--devices", type=int, default=os.cpu_count() or 1,
                        help="JAX CPU devices the environments are split over (default: one per core, as EnvPool "
                             "runs a thread per core; 1: one device, XLA's own threads only)")
    parser.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results", "env_throughput.json"))
    args = parser.parse_args(argv)
    if args.devices < 1:
        raise ValueError(f"--devices must be at least 1, got {args.devices}")
    try:  # one JAX device per core; must come before JAX runs anything
        jax.config.update("jax_num_cpu_devices", args.devices)
    except RuntimeError:
        print(f"note: JAX had started before --devices could apply; {len(jax.devices())} device(s)")
    args.devices = min(args.devices, len(jax.devices()))
    if args.quick:
        args.envs, args.env_steps, args.highway_seconds = [1, 256, 4096], 1 << 16, 5.0
        args.task_envs, args.task_env_steps, args.envpool_seconds = [1, 16], 256, 3.0
    known = set(envs_jax.available_scenarios())
    bad = sorted(set(args.scenarios) - known)
    if bad:
        raise ValueError(f"unknown scenario(s) {bad}; allowed: {sorted(known)}")
    baseline = None
    if args.baseline:
        with open(args.baseline) as f:
            baseline = json.load(f)

    results = {"machine": {"platform": platform.platform(), "processor": platform.processor(),
                           "cpus": os.cpu_count(), "jax": jax.__version__,
                           "device": str(jax.devices()[0]), "devices": args.devices}, "scenarios": {}, "tasks": {}}
    if baseline is not None:
        results["baseline"] = args.baseline
    print(f"device: {jax.devices()[0]}, {os.cpu_count()} CPUs, jax {jax.__version__}, load {load():.1f}")

    def save():  # after every scenario and task: a run cut short keeps what it measured
        os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
        with open(args.out, "w") as f:
            json.dump(results, f, indent=2)

    for name in args.scenarios:
        env = envs_jax.make(name)
        start = load()
        hw = measure_highway(name, args.highway_seconds)
        rows = []
        for n in args.envs:
            t = max(10, args.env_steps // n)
            row = measure_jax(env, n, t, args.repeats, devices=args.devices)
            row["ratio"] = row["steps_per_s"] / hw
            rows.append(row)
        results["scenarios"][name] = {"highway_env_steps_per_s": hw, "jax": rows, "load_start": start,
                                      "load_end": load()}
        print_scenario(name, results["scenarios"][name], baseline)
        save()
    available = set(envs_jax.available_tasks())
    for name in args.tasks:
        if name not in available:
            print(f"\n{name}: skipped, envs_jax.make does not know it (tasks: {sorted(available)})")
            results["tasks"][name] = {"skipped": "not in envs_jax.available_tasks()"}
            continue
        results["tasks"][name] = measure_task(name, args)
        save()
    save()
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
