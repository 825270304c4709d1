"""CSQ for K agents and any hierarchy (jaxsmarl/algos/csq.py): acting and targets against brute-force backward
induction, the two-agent path bit for bit against outputs pinned before hierarchies existed, highway-v0 with K
controlled vehicles through the training loop, and the command line's checks."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxsmarl import networks
from jaxsmarl.algos.csq import CSQAgent, CSQConfig, Transition
from jaxsmarl.hierarchy import validate_hierarchy
from jaxsmarl.metrics import episode_record
from tests.csq_reference import REFERENCE, RUNS, short_run
from tests.test_stackelberg_hierarchy import brute_equilibrium
from train.config import load_config

A, D = 5, 6


def _agent(k, hierarchy, **kw):
    return CSQAgent(CSQConfig(num_actions=(A,) * k, obs_dim=D, hidden_sizes=(16, 16), cost_threshold=(0.0,) * k,
                              eps_start=(0.0,) * k, eps_min=(0.0,) * k, hierarchy=hierarchy, **kw))


@functools.lru_cache(maxsize=None)
def _critics(k, b, seed):
    """Critic parameters, observations and all values; the same for every hierarchy (computed once)."""
    agent = _agent(k, None)
    state = jax.jit(agent.init)(jax.random.PRNGKey(seed))
    obs = 2.0 * jax.random.normal(jax.random.PRNGKey(seed + 1), (b, k, D))
    return state, obs, np.asarray(jax.jit(agent.values)(state.params, obs))  # values [B, k, 2, A..A]


def _setup(k, hierarchy, b=8, seed=0):
    return (_agent(k, hierarchy),) + _critics(k, b, seed)


def _brute(values_b, levels, d=0.0):
    k = values_b.shape[0]
    return brute_equilibrium([values_b[i, 0] for i in range(k)], [values_b[i, 1] for i in range(k)], [d] * k, levels)


@pytest.mark.parametrize("hierarchy", ["2|0|1", "0|1,2", "1,2|0", "0,1,2"])
def test_greedy_action_is_the_hierarchy_equilibrium(hierarchy):
    agent, state, obs, values = _setup(3, hierarchy)
    levels = validate_hierarchy(hierarchy, 3)
    got = np.asarray(jax.jit(agent.greedy_act)(state, obs))
    np.testing.assert_array_equal(got, [_brute(v, levels) for v in values])


def test_lower_levels_respond_to_the_executed_actions_above():
    """'0|1,2' with the leader always exploring: agents 1 and 2 play their level's equilibrium given the leader's
    executed (random) action; with agent 1 always exploring, agent 2 still plays its part of the level's
    equilibrium (it does not see a same-level action) and the leader is greedy."""
    agent, state, obs, values = _setup(3, "0|1,2", b=16, seed=4)
    act = jax.jit(agent.act)
    a = np.asarray(act(state, obs, jax.random.PRNGKey(0), jnp.array([1.0, 0.0, 0.0])))
    for b in range(16):
        sub = values[b][:, :, a[b, 0]]  # the game of agents 1, 2 once the leader has played
        want = brute_equilibrium([sub[i, 0] for i in (1, 2)], [sub[i, 1] for i in (1, 2)], [0.0, 0.0], ((0, 1),))
        assert tuple(a[b, 1:]) == want
    assert len(set(a[:, 0])) > 2
    greedy = np.asarray(jax.jit(agent.greedy_act)(state, obs))
    np.testing.assert_array_equal(act(state, obs, jax.random.PRNGKey(1), jnp.zeros(3)), greedy)
    a = np.asarray(act(state, obs, jax.random.PRNGKey(1), jnp.array([0.0, 1.0, 0.0])))
    np.testing.assert_array_equal(a[:, [0, 2]], greedy[:, [0, 2]])
    assert len(set(a[:, 1])) > 2
    # a chain led by agent 2: agents 0 and 1 answer agent 2's executed action, in the chain 0 | 1
    agent, state, obs, values = _setup(3, "2|0|1", b=16, seed=4)
    a = np.asarray(jax.jit(agent.act)(state, obs, jax.random.PRNGKey(2), jnp.array([0.0, 0.0, 1.0])))
    for b in range(16):
        sub = values[b][:, :, :, :, a[b, 2]]
        want = brute_equilibrium([sub[i, 0] for i in (0, 1)], [sub[i, 1] for i in (0, 1)], [0.0, 0.0], ((0,), (1,)))
        assert tuple(a[b, :2]) == want


@pytest.mark.parametrize("k, hierarchy, infeasible", [
    (3, "2|0|1", "min_cost"), (4, "3|1|0|2", "argmax"),  # chains
    (3, "0,1|2", "min_cost"), (4, "0,1|2,3", "min_cost"), (4, "2|0,3|1", "argmax"), (4, "3|0,1,2", "min_cost"),
])
def test_targets_evaluate_only_what_backward_induction_needs(k, hierarchy, infeasible):
    """The target equilibrium of a hierarchy of several levels (chains, levels of several agents) from the critic
    rows backward induction needs == the full grid's."""
    agent = _agent(k, hierarchy, infeasible=infeasible)
    state = _critics(k, 8, 0)[0] if k == 3 else jax.jit(agent.init)(jax.random.PRNGKey(0))
    obs = 2.0 * jax.random.normal(jax.random.PRNGKey(7), (200, k, D))
    fast = jax.jit(agent.solve_equilibrium)(state.params, obs)
    full = jax.jit(lambda p, o: agent.equilibrium(agent.values(p, o)))(state.params, obs)
    np.testing.assert_array_equal(fast, full)


def test_td_targets_bootstrap_at_the_hierarchy_equilibrium():
    """y_i = (r_i, c_i) + gamma (1 - t_i) (Q_i, G_i)^targ(s', a'), a' the equilibrium of the online critics at s'."""
    agent, state, _, _ = _setup(3, "0,1|2")
    target = _critics(3, 16, 4)[0].params
    state = state.replace(target_params=target)
    k = jax.random.split(jax.random.PRNGKey(10), 4)
    b = 8
    batch = Transition(obs=jax.random.normal(k[0], (b, 3, D)), action=jax.random.randint(k[1], (b, 3), 0, A),
                       reward=jax.random.normal(k[2], (b, 3)), cost=jnp.abs(jax.random.normal(k[3], (b, 3))),
                       next_obs=2.0 * jax.random.normal(k[0], (b, 3, D)),
                       terminated=jnp.array([[False, True, False]] * b), truncated=jnp.zeros((b,), bool))
    y = np.asarray(jax.jit(agent.td_targets)(state, batch, jax.random.PRNGKey(0), jnp.zeros(3)))
    v_online = np.asarray(agent.values(state.params, batch.next_obs))
    levels = validate_hierarchy("0,1|2", 3)
    a_next = jnp.asarray([_brute(v, levels) for v in v_online], jnp.int32)
    boot = np.asarray(networks.values_at(target, batch.next_obs, a_next, (A,) * 3))
    rc = np.stack([batch.reward, batch.cost], -1)
    keep = np.array([1.0, 0.0, 1.0])[None, :, None]
    np.testing.assert_allclose(y, rc + 0.95 * keep * boot, rtol=1e-5, atol=1e-6)


def test_episode_record_of_k_agents():
    info = {"episode_return": jnp.array([1.0, 2.0, 4.0]), "episode_cost": jnp.array([0.0, 5.0, 5.0]),
            "episode_arrived": jnp.array([False, False, True]), "episode_distance": jnp.array([10.0, 20.0, 30.0]),
            "returned_episode": jnp.array(True), "episode_crash": jnp.array(True), "episode_length": jnp.array(7),
            "episode_offroad": jnp.array(False)}
    r = {k: float(v) for k, v in episode_record(info).items()}
    assert (r["leader_return"], r["follower_return"], r["total_return"]) == (1.0, 6.0, 7.0)
    assert (r["leader_cost"], r["follower_cost"], r["leader_arrived"], r["follower_arrived"]) == (0.0, 10.0, 0.0, 1.0)
    assert (r["leader_distance"], r["follower_distance"], r["length"], r["crash"]) == (10.0, 50.0, 7.0, 1.0)


@pytest.mark.parametrize("name, scenario, preset", [
    RUNS[0], pytest.param(*RUNS[1], marks=pytest.mark.slow)])
def test_two_agent_training_is_bit_identical_to_before_hierarchies(name, scenario, preset):
    ref = np.load(REFERENCE)
    out = short_run(scenario, preset)
    keys = [k for k in ref.files if k.startswith(name + "/")]
    assert len(keys) == len(out) and np.sum(ref[f"{name}/episode_returned"]) > 0
    for k in keys:
        np.testing.assert_array_equal(out[k.split("/", 1)[1]], ref[k], err_msg=k)


def test_traffic_autoreset_statistics_and_flat_observations():
    """The K-agent wrapper against the bare env stepped by hand: flat observations, per-agent sums, reset."""
    import envs_jax
    from envs_jax.traffic_autoreset import TrafficAutoResetWrapper

    env = envs_jax.make("highway-v0", controlled_vehicles=3, vehicles_count=6, duration=4)
    wrapped = TrafficAutoResetWrapper(env)
    params = env.default_params
    obs, ws = wrapped.reset(jax.random.PRNGKey(0), params)
    raw_obs, raw = env.reset(jax.random.PRNGKey(0), params)
    np.testing.assert_array_equal(obs, np.asarray(raw_obs).reshape(3, -1))
    assert wrapped.obs_shape == (3, 25) and obs.shape == (3, 25)
    step = wrapped.step  # eager: it reuses the env's own compiled step and reset
    ret, cst = np.zeros(3), np.zeros(3)
    for t in range(5):
        key, action = jax.random.PRNGKey(100 + t), jnp.array([t % 5, (t + 2) % 5, 1], jnp.int32)
        k_step, _ = jax.random.split(key)
        raw_obs, raw, r, c, done, info_raw = env.step(k_step, raw, action, params)
        obs, ws, r2, c2, done2, info = step(key, ws, action, params)
        np.testing.assert_array_equal(r2, r)
        ret, cst = ret + np.asarray(r), cst + np.asarray(c)
        np.testing.assert_array_equal(info["terminal_obs"], np.asarray(raw_obs).reshape(3, -1))
        assert bool(done2) == bool(done) == (t == 3)  # 4 s at 1 Hz
        if done:
            np.testing.assert_allclose(info["episode_return"], ret, rtol=1e-6)
            np.testing.assert_allclose(info["episode_cost"], cst, rtol=1e-6)
            assert int(info["episode_length"]) == 4 and int(ws.env_state.time) == 0
            assert float(jnp.sum(ws.episode_return)) == 0.0
            break


@pytest.mark.slow
def test_highway_k_agents_trains_through_the_loop():
    """Three controlled vehicles, one leader and two followers, through the off-policy loop and the greedy
    evaluation; the critics' loss falls."""
    from train.build import make_train
    from train.trainer import seed_keys

    cfg = load_config("highway", "csq", dict(agents=3, hierarchy="0|1,2", total_steps=120, num_envs=2, chunk_steps=120,
                                             num_seeds=1, warmup=16, batch_size=16, checkpoint_every=0,
                                             eval_episodes=1, eval_max_steps=5))
    trainer = make_train(cfg)
    state, m = jax.jit(trainer.train)(seed_keys(cfg)[0])
    loss = np.asarray(m["update"]["loss_q"])
    assert loss.shape == (60, 3) and np.all(np.isfinite(loss)) and loss[-5:].mean() < loss[8:13].mean()
    rec = jax.jit(trainer.evaluate)(state.agent, jax.random.PRNGKey(0))
    assert rec["length"].shape == (1,)


@pytest.mark.parametrize("scenario, overrides, message", [
    ("merge", {"agents": 9}, "'agents' for scenario 'merge' must be 2..8"),
    ("highway", {"agents": 5}, "at most 4 agents"),
    ("highway", {"agents": 9}, "must be 2..8"),
    ("highway", {"agents": 3, "hierarchy": "0|1"}, r"misses agent\(s\) \[2\].*'0\|1\|2' \(vertical chain\)"),
    ("highway", {"agents": 3, "hierarchy": "0,1|2", "leader_rule": "authors"}, "needs a chain"),
    ("highway", {"agents": 3, "cost_threshold": [1, 2]}, "list of 3 numbers, one per agent"),
])
def test_bad_combinations_are_refused(scenario, overrides, message):
    with pytest.raises(ValueError, match=message):
        load_config(scenario, "csq", overrides)


def test_per_agent_values_and_hierarchy_normalised():
    cfg = load_config("highway", "csq", {"agents": 4, "hierarchy": " 1,0 | 3|2"})
    assert cfg["agents"] == 4 and cfg["hierarchy"] == "0,1|3|2"
    assert cfg["cost_threshold"] == [5.0] * 4 and cfg["eps_start"] == [0.1] * 4
    assert load_config("merge", "csq")["agents"] == 2 and load_config("merge", "csq")["hierarchy"] is None
