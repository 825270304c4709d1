"""Several training processes through jax.distributed (train/distributed.py), on this machine: CPU devices, gloo
collectives over the loopback, the coordinator on 127.0.0.1.

The truth for the two-process run is the same command as one process with two devices: each device holds the
same two seeds in both, so every seed is computed by the same program and must agree bit for bit (episodes,
greedy evaluation, the whole checkpointed training state).
"""

import os
import signal
import socket
import subprocess
import sys
import time

import jax
import numpy as np
import pytest

from jaxsmarl.checkpoints import Checkpointer

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# 4 seeds, 2 chunks with a checkpoint after each, a short greedy evaluation
TINY = ["--scenario", "merge", "--algo", "csq", "--seeds", "4", "--steps", "100", "--chunk-steps", "50",
        "--checkpoint-every", "50", "--set", "warmup=32", "--set", "batch_size=16", "--set", "buffer_size=100",
        "--set", "hidden_sizes=[16,16]", "--eval-episodes", "1", "--quiet"]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def env_with(devices: int) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_")}
    env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    return env


def start(args: list[str], devices: int, log) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "train", *args], cwd=ROOT, env=env_with(devices), stdout=log,
                            stderr=subprocess.STDOUT)


def cluster_args(port: int, n: int, i: int) -> list[str]:
    return ["--coordinator-address", f"127.0.0.1:{port}", "--num-processes", str(n), "--process-id", str(i)]


def start_pair(args: list[str], tmp, name: str):
    port = free_port()
    logs = [open(tmp / f"{name}.{i}.log", "w+") for i in range(2)]
    procs = [start(args + cluster_args(port, 2, i), 1, logs[i]) for i in range(2)]
    return procs, logs


def read(log) -> str:
    log.flush()
    log.seek(0)
    return log.read()


def restore_all(run_dir: str):
    from train.restore import restore_run

    config, _, state, meta = restore_run(run_dir)
    return state, meta


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory):
    """The same 4-seed run by two processes of one device each and by one process of two devices, side by side."""
    tmp = tmp_path_factory.mktemp("dist")
    procs, logs = start_pair(TINY + ["--out", str(tmp / "multi")], tmp, "multi")
    with open(tmp / "single.log", "w+") as slog:
        single = start(TINY + ["--out", str(tmp / "single")], 2, slog)
        rcs = [p.wait(timeout=600) for p in procs + [single]]
        texts = [read(f) for f in logs] + [read(slog)]
    assert rcs == [0, 0, 0], "\n----\n".join(t[-3000:] for t in texts)
    return tmp


def test_two_processes_reproduce_one_process_seed_for_seed(two_runs):
    multi, single = str(two_runs / "multi"), str(two_runs / "single")
    # process 0 wrote the run folder's files
    assert sorted(f for f in os.listdir(multi) if f != ".lock") == sorted(
        f for f in os.listdir(single) if f != ".lock")
    for name in ("episodes.csv", "learner.csv", "eval.csv"):
        with open(os.path.join(multi, name)) as a, open(os.path.join(single, name)) as b:
            got, want = a.read(), b.read()
        assert got == want and len(want.splitlines()) > 1, name
    s_multi, m_multi = restore_all(multi)
    s_single, m_single = restore_all(single)
    assert m_multi["num_processes"] == 2 and m_single["num_processes"] == 1
    assert m_multi["env_steps"] == m_single["env_steps"] == 100
    leaves = jax.tree.leaves(s_single)
    assert leaves and all(x.shape[0] == 4 for x in leaves)
    for a, b in zip(jax.tree.leaves(s_multi), leaves):
        np.testing.assert_array_equal(a, b)
    # both processes' checkpoints hold every seed: the earlier step too
    with Checkpointer(os.path.join(multi, "checkpoints")) as ck:
        assert ck.all_steps() == [50, 100]


def test_resume_refuses_another_process_count(two_runs):
    import json

    import train.run
    from train.config import read_run_config

    multi = str(two_runs / "multi")
    before = json.load(open(os.path.join(multi, "summary.json")))
    with pytest.raises(ValueError, match="trained by 2 processes and this is 1; resume it with --num-processes 2"):
        train.run.run(read_run_config(multi), multi, resume=True, verbose=False)
    assert json.load(open(os.path.join(multi, "summary.json"))) == before


HEARTBEAT_S = 5


@pytest.mark.parametrize("victim", [1, pytest.param(0, marks=pytest.mark.slow)])
def test_killed_process_stops_its_peer_within_the_timeout(tmp_path, victim):
    """kill -9 one process once both have joined (process 0 has written config.json); the other exits with an
    error, not a hang, within the heartbeat timeout (plus start-up slack)."""
    args = TINY[:-1] + ["--steps", "100000", "--eval-episodes", "0", "--quiet", "--heartbeat-timeout",
                        str(HEARTBEAT_S), "--out", str(tmp_path / "run")]
    procs, logs = start_pair(args, tmp_path, "kill")
    try:
        deadline = time.monotonic() + 300
        while not os.path.exists(tmp_path / "run" / "config.json"):
            assert all(p.poll() is None for p in procs), [read(f)[-2000:] for f in logs]
            assert time.monotonic() < deadline, "the processes never started the run"
            time.sleep(0.1)
        procs[victim].send_signal(signal.SIGKILL)
        killed_at = time.monotonic()
        peer = procs[1 - victim]
        rc = peer.wait(timeout=HEARTBEAT_S + 60)
        took = time.monotonic() - killed_at
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    text = read(logs[1 - victim])
    assert rc != 0, text[-2000:]
    assert took < HEARTBEAT_S + 10, (took, text[-2000:])
    assert "another task died" in text or "unhealthy" in text or "coordination service" in text, text[-2000:]
