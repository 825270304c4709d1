"""MAPPO-L / MACPO: the multiplier rule, one update on a constructed rollout, and a short run end to end."""

import json
import os

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl import columns
from jaxsmarl.algos.mappo_l import MAPPOL, lagrange_step
from jaxsmarl.algos.ppo_base import PPOConfig
from jaxsmarl.layout import ENV_VAR
from jaxsmarl.mlp import MLP, mlp_columns, mlp_rows
from jaxsmarl.permutation import random_permutation
from train import __main__ as cli
from train.config import load_config
from train.onpolicy import Transition


def test_lagrange_step_closed_form():
    # max(0, lam + lr [(J_c - d)(1 - gamma) + E(ratio A_c)])
    assert float(lagrange_step(0.78, 3.0, 1.0, 0.9, 0.5, 0.1)) == pytest.approx(0.78 + 0.5 * (0.2 + 0.1))
    assert float(lagrange_step(0.01, 0.0, 1.0, 0.9, 0.5, 0.0)) == 0.0  # projected at 0


def _rollout(T, E, ep_cost, key):
    k = jax.random.split(key, 4)
    ended = jnp.zeros((T, E), bool).at[-1].set(True)
    return Transition(obs=jax.random.normal(k[0], (T, E, 2, 8)), action=jax.random.normal(k[1], (T, E, 2, 1)),
                      logp=jnp.full((T, E, 2), -1.0), reward=jax.random.normal(k[2], (T, E, 2)),
                      cost=jax.random.uniform(k[3], (T, E, 2)), next_obs=jax.random.normal(k[0], (T, E, 2, 8)),
                      terminated=jnp.zeros((T, E, 2), bool), done=ended, active=jnp.ones((T, E, 2), bool),
                      ep_returned=ended, ep_cost=jnp.full((T, E, 2), ep_cost))


@pytest.mark.parametrize("ep_cost, rises", [pytest.param(5.0, True, marks=pytest.mark.slow), (0.0, False)])
def test_lambda_rises_while_episode_cost_exceeds_limit(ep_cost, rises):
    # gamma 0.5: the constraint term (J_c - d)(1 - gamma) = +-2 or -0.5 dominates E(ratio A_c) (standardised A_c)
    agent = MAPPOL(PPOConfig(cost_limit=1.0, gamma=0.5, lambda_lr=0.05, num_minibatches=2, ppo_epochs=2, hidden=8))
    st = agent.init(jax.random.PRNGKey(0))
    lam = [0.78]
    for i in range(3):
        st, info = jax.jit(agent.update)(st, _rollout(8, 4, ep_cost, jax.random.PRNGKey(i)), jax.random.PRNGKey(i))
        lam.append(float(st.lagrange[0]))
        np.testing.assert_allclose(st.episode_cost, [ep_cost, ep_cost])
    steps = np.diff(lam)
    assert (steps > 0).all() if rises else (steps < 0).all(), lam


def test_sequential_factor_is_previous_agents_ratio():
    """With sequential updates the second agent's data are weighted by the first agent's new/old ratio; with a
    zero learning rate for the first agent the factor is 1 and both orders give the same second-agent update."""
    cfg = dict(num_minibatches=2, ppo_epochs=1, hidden=8, sequential=True)
    traj = _rollout(8, 4, 1.0, jax.random.PRNGKey(3))
    st0 = MAPPOL(PPOConfig(**cfg)).init(jax.random.PRNGKey(0))
    # ratio 1 at the start: behaviour log-probs equal to the current policy's
    agent = MAPPOL(PPOConfig(**cfg))
    mean, std = agent._all_dists(st0, agent.normalize_obs(st0, traj.obs.reshape(-1, 2, 8)))
    from jaxsmarl.gaussian import gaussian_log_prob
    logp = gaussian_log_prob(traj.action.reshape(-1, 2, 1), mean, std).reshape(8, 4, 2)
    traj = traj.replace(logp=logp)
    st_seq, _ = jax.jit(agent.update)(st0, traj, jax.random.PRNGKey(5))
    st_sim, _ = jax.jit(MAPPOL(PPOConfig(**{**cfg, "sequential": False})).update)(st0, traj, jax.random.PRNGKey(5))
    # Both update every actor; the sequential one differs only through the factor (non-trivial after a step).
    d = jax.tree.map(lambda a, b: float(jnp.max(jnp.abs(a - b))), st_seq.actor, st_sim.actor)
    assert max(jax.tree.leaves(d)) > 0


@pytest.mark.parametrize("algo", ["mappo-l", pytest.param("macpo", marks=pytest.mark.slow)])
def test_short_run_end_to_end_with_resume_and_eval(tmp_path, algo, capsys):
    out = str(tmp_path / algo)
    args = ["--scenario", "racetrack", "--algo", algo, "--seeds", "1", "--steps", "512", "--num-envs", "16",
            "--chunk-steps", "256", "--checkpoint-every", "256", "--eval-episodes", "2", "--quiet",
            "--set", "rollout_length=8", "--set", "num_minibatches=4", "--set", "eval_max_steps=20",
            "--out", out]
    import train.run

    cfg = cli.build_config(cli.parse_args(args))
    train.run.run(cfg, out, verbose=False, max_chunks=1)  # interrupted after one chunk
    assert cli.main(args + ["--resume"]) == 0
    summ = json.load(open(os.path.join(out, "summary.json")))
    assert summ["finished"] and summ["summary"]["episodes_per_seed"][0] > 0
    assert np.isfinite(summ["summary"]["total_return"]["last"][0])
    assert cli.main(["--eval-only", out, "--eval-episodes", "2"]) == 0
    printed = capsys.readouterr().out
    ev = json.loads(printed[printed.rfind('{\n  "env_steps"'):])
    assert ev["env_steps"] == 512 and len(ev["total_return"]["per_seed"]) == 1
    assert os.path.exists(os.path.join(out, "eval.csv"))


def test_macpo_update_respects_trust_region():
    """One MACPO update on a constructed rollout: every accepted step has mean KL below the threshold (the
    line search's rule) and the parameters stay finite; a rejected search leaves the actor unchanged."""
    from jaxsmarl.algos.macpo import MACPO

    agent = MACPO(PPOConfig(num_minibatches=2, hidden=8, kl_threshold=0.01, cost_limit=1.0))
    st0 = agent.init(jax.random.PRNGKey(0))
    st, info = jax.jit(agent.update)(st0, _rollout(8, 4, 3.0, jax.random.PRNGKey(1)), jax.random.PRNGKey(2))
    assert all(np.isfinite(x).all() for x in jax.tree.leaves(st.actor))
    kl, acc = np.asarray(info["kl"]), np.asarray(info["accepted"])
    assert (kl < 0.01).all() and (kl[acc == 0] == 0).all()
    np.testing.assert_allclose(np.asarray(info["case"]).sum(-1), 1.0)  # one case per agent and minibatch (mean)


def test_config_rejects_partial_cycles():
    with pytest.raises(ValueError, match="multiple of num_envs \\* rollout_length"):
        load_config("racetrack", "macpo", {"num_envs": 16, "rollout_length": 8, "total_steps": 1040,
                                            "chunk_steps": 128})
    with pytest.raises(ValueError, match="multiple of num_minibatches"):
        load_config("racetrack", "mappo-l", {"num_envs": 16, "rollout_length": 8, "total_steps": 1280,
                                              "chunk_steps": 128, "num_minibatches": 3})


@pytest.mark.parametrize("n", [1, 2, 7, 512, 8192, 10_000])
def test_random_permutation_is_a_permutation(n):
    perms = jax.jit(jax.vmap(lambda k: random_permutation(k, n)))(jax.random.split(jax.random.PRNGKey(0), 4))
    assert perms.dtype == jnp.int32 and perms.shape == (4, n)
    for p in np.asarray(perms):
        np.testing.assert_array_equal(np.sort(p), np.arange(n))


def test_random_permutation_is_uniform():
    """Every one of the 4! orders of 4 elements equally likely (chi-square, 24,000 draws; p ~ 1e-4 threshold),
    and each eighth of range(8192) equally likely at the first and at the last position (4,000 draws)."""
    perms = np.asarray(jax.jit(jax.vmap(lambda k: random_permutation(k, 4)))(
        jax.random.split(jax.random.PRNGKey(1), 24_000)))
    codes = perms @ np.array([64, 16, 4, 1])
    counts = np.array([np.sum(codes == c) for c in np.unique(codes)])
    assert len(counts) == 24
    chi2 = np.sum((counts - 1000.0) ** 2 / 1000.0)
    assert chi2 < 55.0, chi2  # chi-square, 23 degrees of freedom: P(> 55) ~ 2e-4

    big = np.asarray(jax.jit(jax.vmap(lambda k: random_permutation(k, 8192)))(
        jax.random.split(jax.random.PRNGKey(2), 4_000)))
    for pos in (0, 8191):
        # which eighth of range(8192) lands at this position: uniform over 8 bins
        counts = np.bincount(big[:, pos] // 1024, minlength=8)
        chi2 = np.sum((counts - 500.0) ** 2 / 500.0)
        assert chi2 < 30.0, (pos, counts)  # 7 degrees of freedom: P(> 30) ~ 1e-4


def test_random_permutation_rejects_bad_sizes():
    for n in (0, -3, 2.5):
        with pytest.raises(ValueError, match="positive int"):
            random_permutation(jax.random.PRNGKey(0), n)


@pytest.mark.parametrize("layout", ["columns", "rows"])
@pytest.mark.parametrize("layer_n,feature_norm", [(0, True), (1, True), (2, False)])
def test_mlp_columns_and_rows_are_the_mlp_with_its_gradients(layout, layer_n, feature_norm, x64):
    """The column-layout network (update loops) and the row network with transposed-input weight gradients
    (MACPO's Fisher products) against the flax module: outputs and every parameter's gradient, float64, with and
    without the input LayerNorm; also under vmap (seeds on one device)."""
    net = MLP(64, layer_n, 2, 0.01, feature_norm)
    params = net.init(jax.random.PRNGKey(0), jnp.zeros((1, 8), jnp.float64))
    params = jax.tree.map(lambda p: p.astype(jnp.float64) + 0.1 * jax.random.normal(jax.random.PRNGKey(5), p.shape,
                                                                                    jnp.float64), params)
    x = 3.0 * jax.random.normal(jax.random.PRNGKey(1), (200, 8), jnp.float64)
    w = jax.random.normal(jax.random.PRNGKey(2), (200, 2), jnp.float64)
    apply = ((lambda p, x: mlp_columns(p, x.T, layer_n, feature_norm).T) if layout == "columns"
             else (lambda p, x: mlp_rows(p, x, layer_n, feature_norm)))
    np.testing.assert_allclose(apply(params, x), net.apply(params, x), rtol=1e-12, atol=1e-12)
    loss_ref = lambda p, x: jnp.sum(w * jnp.tanh(net.apply(p, x)))
    loss_col = lambda p, x: jnp.sum(w * jnp.tanh(apply(p, x)))
    for a, b in zip(jax.tree.leaves(jax.grad(loss_ref)(params, x)), jax.tree.leaves(jax.grad(loss_col)(params, x))):
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-12)
    xs = jnp.stack([x, -x])
    ps = jax.tree.map(lambda p: jnp.stack([p, 2.0 * p]), params)
    for a, b in zip(jax.tree.leaves(jax.vmap(jax.grad(loss_ref))(ps, xs)),
                    jax.tree.leaves(jax.jit(jax.vmap(jax.grad(loss_col)))(ps, xs))):
        np.testing.assert_allclose(b, a, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("B", [7, 16, 37])
def test_in_chunks_is_the_function_on_all_samples(B):
    """columns.in_chunks: the same rows as the function on the whole batch, also when the batch is not a whole
    number of chunks (zero padding dropped) or fits one chunk; several inputs and a tuple of outputs."""
    x = jax.random.normal(jax.random.PRNGKey(0), (B, 3))
    y = jax.random.normal(jax.random.PRNGKey(1), (B, 2, 3))
    fn = lambda x, y: (jnp.sum(y * x[:, None], -1), jnp.tanh(x) @ jnp.arange(6.0).reshape(3, 2))
    for a, b in zip(jax.jit(lambda x, y: columns.in_chunks(fn, x, y, chunk=8))(x, y), fn(x, y)):
        assert a.shape == b.shape
        np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("algo", ["mappo-l", pytest.param("macpo", marks=pytest.mark.slow)])  # one default
def test_update_is_the_same_in_both_layouts(algo, monkeypatch):
    """A whole update with the column layout (XLA:CPU: advantage preparation with the critics' values computed
    chunk by chunk, the sequential factor's log-probs likewise, the actor loss and the unrolled critics' steps
    with each network as one vector) gives the same new state as the row layout with vmapped critics (other
    backends), which uses no column layer anywhere."""
    from jaxsmarl.algos.macpo import MACPO
    traj = _rollout(40, 30, 1.0, jax.random.PRNGKey(2))  # 1200 samples: 3 chunks of 512, the last one padded
    out = {}
    for flag in (True, False):
        monkeypatch.setenv(ENV_VAR, "columns" if flag else "rows")
        agent = (MAPPOL if algo == "mappo-l" else MACPO)(PPOConfig(num_minibatches=4, ppo_epochs=2))
        st = agent.init(jax.random.PRNGKey(1))
        out[flag] = jax.jit(agent.update)(st, traj, jax.random.PRNGKey(0))
        jaxpr = str(jax.make_jaxpr(agent.update)(st, traj, jax.random.PRNGKey(0)))
        assert ("custom_vjp" in jaxpr) == flag
    for a, b in zip(jax.tree.leaves(out[True]), jax.tree.leaves(out[False])):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5)


def test_flat_parameters_round_trip_and_take_the_same_adam_steps(x64):
    """flat.to_flat / from_flat: the trees come back bit for bit, and clipped Adam steps on the one-vector
    form (the CPU minibatch loops) give the tree form's parameters and moments (float64)."""
    import optax

    from jaxsmarl.flat import from_flat, to_flat
    net = MLP(16, 1, 2, 1.0, True)
    params = net.init(jax.random.PRNGKey(0), jnp.zeros((1, 5), jnp.float64))
    params = jax.tree.map(lambda p: p.astype(jnp.float64), {"net": params, "log_std": jnp.array([0.3, -0.2])})
    tx = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(1e-2, eps=1e-5))
    opt = tx.init(params)
    x = jax.random.normal(jax.random.PRNGKey(1), (7, 5), jnp.float64)
    loss = lambda p: jnp.sum(net.apply(p["net"], x) ** 2) + jnp.sum(p["log_std"] ** 3)

    def tree_step(params, opt):
        upd, opt = tx.update(jax.grad(loss)(params), opt, params)
        return optax.apply_updates(params, upd), opt

    params, opt = tree_step(params, opt)  # non-zero moments to convert
    flat, fopt = to_flat(params, opt)
    for a, b in zip(jax.tree.leaves(from_flat(flat, fopt)), jax.tree.leaves((params, opt))):
        np.testing.assert_array_equal(a, b)
    for _ in range(3):  # gradient norms ~10: the clip is active
        params, opt = tree_step(params, opt)
        fupd, fopt = tx.update(jax.grad(lambda f: loss(f.tree()))(flat), fopt, flat)
        flat = optax.apply_updates(flat, fupd)
    for a, b in zip(jax.tree.leaves(from_flat(flat, fopt)), jax.tree.leaves((params, opt))):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-14)
