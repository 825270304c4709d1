"""Scaling of seeds over processes and of sweeps in one program (docs/distributed.md).

1. Processes: the same seeds trained by one process on two cores (two CPU devices) against two processes on one
   core each (``taskset``, one device each, jax.distributed with gloo over the loopback). Ratio: throughput of
   the two processes over that of the one (1.0 = no cost for going multi-process).
2. Sweeps: ``--sweep lr=[8 values]`` x 4 seeds in one program against the same 8 configurations as 8 runs one
   after another. Ratios: wall time (compile included) and training time of the runs over those of the sweep.

Every measurement is a real ``python -m train`` command; the numbers come from its ``summary.json`` /
``sweep.json`` timing and the command's wall time. Results: ``benchmarks/results/scaling.json``.

    python benchmarks/scaling.py [--steps 2000] [--seeds 4] [--configs 8]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def base_args(steps: int, seeds: int) -> list[str]:
    return ["--scenario", "merge", "--algo", "csq", "--seeds", str(seeds), "--steps", str(steps),
            "--chunk-steps", str(steps // 2), "--checkpoint-every", "0", "--eval-episodes", "0", "--quiet"]


def env_for(devices: int) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    return env


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def launch(args: list[str], devices: int, cores: str | None = None) -> subprocess.Popen:
    cmd = ([] if cores is None else ["taskset", "-c", cores]) + [sys.executable, "-m", "train", *args]
    return subprocess.Popen(cmd, cwd=ROOT, env=env_for(devices), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def finish(procs: list[subprocess.Popen]) -> None:
    outs = [p.communicate()[0] for p in procs]
    for p, o in zip(procs, outs):
        if p.returncode != 0:
            raise RuntimeError(f"a training process failed ({p.returncode}):\n{o[-3000:]}")


def timing(run_dir: str) -> dict:
    with open(os.path.join(run_dir, "summary.json")) as f:
        return json.load(f)["timing"]


def processes(tmp: str, steps: int, seeds: int) -> dict:
    args = base_args(steps, seeds)
    one = os.path.join(tmp, "one")
    t = time.perf_counter()
    finish([launch(args + ["--out", one], 2, "0,1")])
    one_wall = time.perf_counter() - t
    two = os.path.join(tmp, "two")
    port = free_port()
    t = time.perf_counter()
    finish([launch(args + ["--out", two, "--coordinator-address", f"127.0.0.1:{port}", "--num-processes", "2",
                           "--process-id", str(i)], 1, str(i)) for i in range(2)])
    two_wall = time.perf_counter() - t
    a, b = timing(one), timing(two)
    with open(os.path.join(one, "episodes.csv")) as f1, open(os.path.join(two, "episodes.csv")) as f2:
        same = f1.read() == f2.read()
    return {"seeds": seeds, "steps_per_seed": steps,
            "one_process_two_cores": {"train_s": a["train_s"], "steps_per_s_all_seeds": a["env_steps_per_s_all_seeds"],
                                      "compile_s": a["compile_s"], "wall_s": one_wall},
            "two_processes_one_core_each": {"train_s": b["train_s"],
                                            "steps_per_s_all_seeds": b["env_steps_per_s_all_seeds"],
                                            "compile_s": b["compile_s"], "wall_s": two_wall},
            "throughput_ratio_two_processes_over_one": b["env_steps_per_s_all_seeds"] / a["env_steps_per_s_all_seeds"],
            "wall_ratio_one_over_two": one_wall / two_wall,
            "episodes_identical": same}


def sweeps(tmp: str, steps: int, seeds: int, n_configs: int) -> dict:
    lrs = [round(1e-3 * (0.5 + 0.25 * i), 6) for i in range(n_configs)]
    args = base_args(steps, seeds)
    out = os.path.join(tmp, "sweep")
    t = time.perf_counter()
    finish([launch(args + ["--out", out, "--sweep", f"lr={json.dumps(lrs)}"], 2, "0,1")])
    sweep_wall = time.perf_counter() - t
    with open(os.path.join(out, "sweep.json")) as f:
        st = json.load(f)["timing"]
    seq_wall, seq_train, seq_compile, same = 0.0, 0.0, 0.0, True
    for i, lr in enumerate(lrs):
        d = os.path.join(tmp, f"run{i}")
        t = time.perf_counter()
        finish([launch(args + ["--out", d, "--set", f"lr={lr}"], 2, "0,1")])
        seq_wall += time.perf_counter() - t
        tm = timing(d)
        seq_train += tm["train_s"]
        seq_compile += tm["compile_s"]
        folder = os.path.join(out, "configs", f"lr={lr:g}")
        with open(os.path.join(folder, "episodes.csv")) as f1, open(os.path.join(d, "episodes.csv")) as f2:
            same = same and f1.read() == f2.read()
    return {"configs": n_configs, "seeds": seeds, "steps_per_seed": steps, "lrs": lrs,
            "sweep": {"wall_s": sweep_wall, "train_s": st["train_s"], "compile_s": st["compile_s"]},
            "sequential_runs": {"wall_s": seq_wall, "train_s": seq_train, "compile_s": seq_compile},
            "wall_ratio_sequential_over_sweep": seq_wall / sweep_wall,
            "train_ratio_sequential_over_sweep": seq_train / st["train_s"],
            "episodes_identical": same}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--configs", type=int, default=8)
    p.add_argument("--only", choices=("processes", "sweeps"), default=None)
    p.add_argument("--out", default=os.path.join(ROOT, "benchmarks", "results", "scaling.json"))
    a = p.parse_args(argv)
    tmp = tempfile.mkdtemp(prefix="scaling_")
    res = {"machine": {"cpus": os.cpu_count(), "load_avg_start": os.getloadavg()},
           "command": "python benchmarks/scaling.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    try:
        if a.only in (None, "processes"):
            res["processes"] = processes(tmp, a.steps, a.seeds)
            r = res["processes"]
            print(f"processes: 2 x 1 core / 1 x 2 cores throughput ratio "
                  f"{r['throughput_ratio_two_processes_over_one']:.2f} (wall ratio {r['wall_ratio_one_over_two']:.2f}; "
                  f"identical episodes: {r['episodes_identical']})", flush=True)
        if a.only in (None, "sweeps"):
            res["sweeps"] = sweeps(tmp, a.steps, a.seeds, a.configs)
            r = res["sweeps"]
            print(f"sweeps: {a.configs} sequential runs / one sweep: "
                  f"wall {r['wall_ratio_sequential_over_sweep']:.2f}x, "
                  f"training {r['train_ratio_sequential_over_sweep']:.2f}x (identical episodes: "
                  f"{r['episodes_identical']})", flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    res["machine"]["load_avg_end"] = os.getloadavg()
    os.makedirs(os.path.dirname(a.out), exist_ok=True)
    with open(a.out, "w") as f:
        json.dump(res, f, indent=2)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
