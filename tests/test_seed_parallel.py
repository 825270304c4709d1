"""Seeds split over CPU devices without a start-up hang (the MAPPO-L / MACPO multi-seed hang).

The hang: with ``jax_num_cpu_devices = 2`` on 2 cores, both devices initialised their seeds at once and both
threads of XLA:CPU's intra-op pool sat in LAPACK's QR kernel (``jax.nn.initializers.orthogonal``), each
waiting for work it had queued on that same, fully blocked pool. A hang is intermittent, so these checks look
at the compiled programs instead, which is deterministic: no custom call in the PPO agent's init, and no
cross-device collective in a seed-parallel program (:func:`train.parallel.seed_parallel`).
"""

import os
import subprocess
import sys
import textwrap

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl.algos.mappo_l import MAPPOL
from jaxsmarl.algos.ppo_base import PPOConfig
from jaxsmarl.initializers import orthogonal_init
from train.parallel import seed_loop
from train.trainer import seed_keys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
COLLECTIVES = ("all-reduce", "all-gather", "collective-permute", "all-to-all", "reduce-scatter")


@pytest.mark.parametrize("shape", [(64, 64), (16, 64), (64, 2), (5, 3)])
def test_orthogonal_init_equals_jax_qr_recipe(shape):
    # jax's initializer (LAPACK QR, sign-fixed) is the truth; same key, same draw -> the same matrix.
    for i in range(5):
        key = jax.random.PRNGKey(i)
        got = orthogonal_init(1.5)(key, shape)
        want = jax.nn.initializers.orthogonal(1.5)(key, shape)
        np.testing.assert_allclose(got, want, atol=2e-5)
        small = min(shape)
        gram = got.T @ got if shape[0] >= shape[1] else got @ got.T
        np.testing.assert_allclose(gram, 2.25 * np.eye(small), atol=1e-4)


def test_ppo_agent_init_has_no_custom_call():
    # A LAPACK custom call here is what deadlocked two devices initialising at once.
    agent = MAPPOL(PPOConfig(n_agents=2, obs_dim=8, hidden=8))
    hlo = jax.jit(jax.vmap(agent.init)).lower(jax.random.split(jax.random.PRNGKey(0), 2)).compile().as_text()
    assert "custom-call(" not in hlo


_TWO_DEVICES = textwrap.dedent("""
    import json, re, sys
    import jax
    jax.config.update("jax_num_cpu_devices", 2)
    import jax.numpy as jnp
    from train.parallel import seed_parallel, seed_sharding

    def fn(x, n):  # a while loop whose trip count depends on the seed's data, like sparse_map's
        def body(c):
            i, acc = c
            return i + 1, acc + jnp.sin(acc) * n
        return jax.lax.while_loop(lambda c: c[0] < jnp.sum(x > 0), body, (0, x))[1]

    x = jax.random.normal(jax.random.PRNGKey(0), (4, 16))
    n = jnp.float32(0.5)
    coll = lambda txt: sorted(set(re.findall(r"\\b(" + "|".join(COLLECTIVES) + r")\\b", txt)))
    par = seed_parallel(fn, 4, in_axes=(0, None))
    seq = seed_parallel(fn, 4, in_axes=(0, None), sequential=True)
    naive = jax.jit(jax.vmap(fn, in_axes=(0, None)), out_shardings=seed_sharding(4))
    alone = jnp.stack([jax.jit(fn)(x[i], n) for i in range(4)])  # each seed by itself
    out = {"devices": len(jax.devices()),
           "parallel": coll(par.lower(x, n).compile().as_text()),
           "sequential": coll(seq.lower(x, n).compile().as_text()),
           "naive": coll(naive.lower(x, n).compile().as_text()),
           "err": float(jnp.max(jnp.abs(par(x, n) - jax.jit(jax.vmap(fn, in_axes=(0, None)))(x, n)))),
           "seq_err": float(jnp.max(jnp.abs(seq(x, n) - alone))),
           "sharded": str(par(x, n).sharding.spec), "seq_sharded": str(seq(x, n).sharding.spec)}
    print(json.dumps(out))
""").replace("COLLECTIVES", repr(COLLECTIVES))


def test_seed_parallel_program_has_no_collectives_on_two_devices():
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    res = subprocess.run([sys.executable, "-c", _TWO_DEVICES], capture_output=True, text=True, env=env, cwd=ROOT,
                         timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    import json

    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["devices"] == 2
    assert out["naive"], "the detector must see the partitioner's all-reduce in the naive program"
    assert out["parallel"] == [] and out["sequential"] == [], out
    assert out["err"] == 0.0 and "seeds" in out["sharded"]
    assert out["seq_err"] == 0.0 and "seeds" in out["seq_sharded"]


def test_seed_loop_runs_each_seed_by_itself():
    # seed i of the looped program is exactly seed i computed alone (unbatched), whatever the other seeds hold
    def fn(p, x, scale):
        h = jnp.tanh(x @ p["w"] + p["b"])
        return {"out": h * scale, "norm": jnp.linalg.norm(h, axis=-1)}

    k = jax.random.split(jax.random.PRNGKey(1), 3)
    p = {"w": jax.random.normal(k[0], (3, 5, 4)), "b": jax.random.normal(k[1], (3, 4))}
    x = jax.random.normal(k[2], (3, 7, 5))
    got = jax.jit(seed_loop(fn, in_axes=(0, 0, None)))(p, x, 2.0)
    for i in range(3):
        want = jax.jit(fn)(jax.tree.map(lambda a: a[i], p), x[i], 2.0)
        for g, w in zip(jax.tree.leaves(got), jax.tree.leaves(want)):
            np.testing.assert_array_equal(g[i], w)
    with pytest.raises(ValueError, match="in_axes"):
        seed_loop(fn, in_axes=(1, 0, None))(p, x, 2.0)


@pytest.mark.parametrize("algo", [pytest.param("mappo-l", marks=pytest.mark.slow), "cs-maddpg"])
def test_training_chunks_run_seeds_in_sequence(algo):
    # Seeds 0 and 1 of a 3-seed run equal those of a 2-seed run, bit for bit: each seed is computed by the same
    # unbatched program (batched programs of 2 and 3 seeds differ in round-off). One seed alone is not compared:
    # XLA inlines a one-trip loop and fuses that program differently.
    import train.programs as programs
    from train.config import load_config

    if jax.default_backend() != "cpu":
        pytest.skip("seeds run one after another only on the CPU backend (train/onpolicy.py, train/algos/maddpg.py)")

    over = {"mappo-l": dict(total_steps=128, num_envs=8, rollout_length=8, num_minibatches=2, ppo_epochs=2,
                            chunk_steps=128),
            "cs-maddpg": dict(total_steps=96, chunk_steps=96, warmup=16, batch_size=8, buffer_size=96)}[algo]
    over.update(checkpoint_every=0, eval_episodes=0)
    final = {}
    for s in (2, 3):
        prog = programs.program(load_config("racetrack", algo, dict(over, num_seeds=s)))
        assert prog["trainer"].seeds_in_sequence
        state = prog["init"](seed_keys(prog["trainer"].config))
        state, _ = prog["chunk"](state, jnp.int32(0))
        final[s] = jax.tree.map(lambda a: np.asarray(a)[:2], state)
    for a, b in zip(jax.tree.leaves(final[2]), jax.tree.leaves(final[3])):
        np.testing.assert_array_equal(a, b)
