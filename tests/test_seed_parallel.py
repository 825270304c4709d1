"""Seeds split over CPU devices without a start-up hang (the MAPPO-L / MACPO multi-seed hang).

The hang: with ``jax_num_cpu_devices = 2`` on 2 cores, both devices initialised their seeds at once and both
threads of XLA:CPU's intra-op pool sat in LAPACK's QR kernel (``jax.nn.initializers.orthogonal``), each
waiting for work it had queued on that same, fully blocked pool. A hang is intermittent, so these checks look
at the compiled programs instead, which is deterministic: no custom call in the PPO agent's init, and no
cross-device collective in a seed-parallel program (:func:`train.run.seed_parallel`).
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
from jaxsmarl.ppo_common import orthogonal_init

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
    from train.run import seed_parallel, seed_sharding

    def fn(x, n):  # a while loop whose trip count depends on the seed's data, like sparse_map's
        def body(c):
            i, acc = c
            return i + 1, acc + jnp.sin(acc) * n
        return jax.lax.while_loop(lambda c: c[0] < jnp.sum(x > 0), body, (0, x))[1]

    x = jax.random.normal(jax.random.PRNGKey(0), (4, 16))
    n = jnp.float32(0.5)
    coll = lambda txt: sorted(set(re.findall(r"\\b(" + "|".join(COLLECTIVES) + r")\\b", txt)))
    par = seed_parallel(fn, 4, in_axes=(0, None))
    naive = jax.jit(jax.vmap(fn, in_axes=(0, None)), out_shardings=seed_sharding(4))
    out = {"devices": len(jax.devices()),
           "parallel": coll(par.lower(x, n).compile().as_text()),
           "naive": coll(naive.lower(x, n).compile().as_text()),
           "err": float(jnp.max(jnp.abs(par(x, n) - jax.jit(jax.vmap(fn, in_axes=(0, None)))(x, n)))),
           "sharded": str(par(x, n).sharding.spec)}
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
    assert out["parallel"] == [], out
    assert out["err"] == 0.0 and "seeds" in out["sharded"]
