"""JaxMARL view: a real ``MultiAgentEnv`` that agrees with the simulator under jit/vmap, runs JaxMARL's IPPO."""

from __future__ import annotations

import functools
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

pytest.importorskip("jaxmarl")
from jaxmarl.environments import spaces as jm_spaces  # noqa: E402
from jaxmarl.environments.multi_agent_env import MultiAgentEnv  # noqa: E402
from jaxmarl.wrappers.baselines import LogWrapper  # noqa: E402

import envs_jax  # noqa: E402
from envs_jax.views import JaxMARLDrivingEnv  # noqa: E402

SCENARIOS = ["merge", "roundabout", "intersection", "racetrack"]
# the long ones: one discrete and one continuous scenario in the default suite, the others under slow
DEFAULT_TWO = ["merge", pytest.param("roundabout", marks=pytest.mark.slow),
               pytest.param("intersection", marks=pytest.mark.slow), "racetrack"]
EXAMPLES = os.path.join(os.path.dirname(__file__), os.pardir, "examples")


@functools.lru_cache(maxsize=None)
def short(name: str):
    """Episodes of 3 s so that a short rollout crosses several auto-resets."""
    return envs_jax.make(name, duration=3.0)


@pytest.mark.parametrize("name", DEFAULT_TWO)
def test_jaxmarl_rollout_matches_the_simulator_under_jit_and_vmap(name):
    """LogWrapper(view) vmapped in one jitted scan equals the simulator's AutoResetWrapper, step by step."""
    env = short(name)
    view = JaxMARLDrivingEnv(env)
    assert isinstance(view, MultiAgentEnv)
    logged, core = LogWrapper(view), envs_jax.AutoResetWrapper(env)
    n, steps = 2, 18

    @jax.jit
    def run(key):
        k_reset, k_run = jax.random.split(key)
        resets = jax.random.split(k_reset, n)
        obs_v, st_v = jax.vmap(logged.reset)(resets)
        obs_c, st_c = jax.vmap(core.reset)(resets)

        def body(carry, key):
            st_v, st_c = carry
            k_act, k_step = jax.random.split(key)
            keys = jax.random.split(k_act, view.num_agents)
            actions = {a: jax.vmap(view.action_space(a).sample)(jax.random.split(keys[i], n))
                       for i, a in enumerate(view.agents)}
            stacked = jnp.stack([actions[a] for a in view.agents], axis=1)
            steps_ = jax.random.split(k_step, n)
            obs_v, st_v, rew_v, done_v, info_v = jax.vmap(logged.step)(steps_, st_v, actions)
            obs_c, st_c, rew_c, cost_c, done_c, info_c = jax.vmap(core.step)(steps_, st_c, stacked)
            out = dict(obs_v=jnp.stack([obs_v[a] for a in view.agents], 1), obs_c=obs_c,
                       rew_v=jnp.stack([rew_v[a] for a in view.agents], 1), rew_c=rew_c,
                       done_v=done_v["__all__"], done_c=done_c,
                       agent_done_v=jnp.stack([done_v[a] for a in view.agents], 1),
                       agent_done_c=info_c["terminated"] | info_c["truncated"][:, None],
                       cost_v=info_v["cost"], cost_c=cost_c,
                       terminal_v=jnp.stack([st_v.env_state.terminal_obs[a] for a in view.agents], 1),
                       terminal_c=info_c["terminal_obs"],
                       ret_v=info_v["returned_episode_returns"], ret_c=info_c["episode_return"],
                       len_v=info_v["returned_episode_lengths"], len_c=info_c["episode_length"],
                       info_shapes=jnp.stack([jnp.asarray(v.shape[1:] == (view.num_agents,))
                                              for v in jax.tree.leaves(info_v)]))
            return (st_v, st_c), out

        _, out = jax.lax.scan(body, (st_v, st_c), jax.random.split(k_run, steps))
        return out

    out = jax.device_get(run(jax.random.key(7)))
    for a, b in [("obs_v", "obs_c"), ("rew_v", "rew_c"), ("cost_v", "cost_c"), ("terminal_v", "terminal_c"),
                 ("done_v", "done_c"), ("agent_done_v", "agent_done_c")]:
        np.testing.assert_array_equal(out[a], out[b], err_msg=f"{a} != {b}")
    ended = out["done_c"]
    assert ended.sum() >= n * 2  # several auto-resets happened in every run
    np.testing.assert_allclose(out["ret_v"][ended], out["ret_c"][ended], rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(out["len_v"][ended][:, 0], out["len_c"][ended])
    assert out["info_shapes"].all()  # every info leaf is [K], as JaxMARL's baselines reshape them


@pytest.mark.parametrize("name", ["merge", "racetrack"])
def test_jaxmarl_spaces_state_safe_step_and_reset_state(name):
    env = short(name)
    view = JaxMARLDrivingEnv(env, world_state=True, terminal_obs_in_infos=True)
    k = env.num_agents
    assert view.agents == [f"agent_{i}" for i in range(k)] and view.num_agents == k
    assert view.agent_classes == {"leader": ["agent_0"], "follower": view.agents[1:]}
    obs_space, act_space = view.observation_space("agent_0"), view.action_space("agent_0")
    assert isinstance(obs_space, jm_spaces.Box) and obs_space.shape == (env.obs_shape[1],)
    assert isinstance(act_space, jm_spaces.Discrete if env.discrete else jm_spaces.Box)
    obs, state = view.reset(jax.random.key(0))
    assert set(obs) == set(view.agents) | {"world_state"}
    np.testing.assert_array_equal(obs["world_state"], view.world_state(state))
    np.testing.assert_array_equal(obs["world_state"], np.concatenate([obs[a] for a in view.agents]))
    avail = view.get_avail_actions(state)
    assert set(avail) == set(view.agents) and all(bool(m.all()) for m in avail.values())
    actions = {a: view.action_space(a).sample(jax.random.key(i)) for i, a in enumerate(view.agents)}
    assert all(bool(view.action_space(a).contains(actions[a])) for a in view.agents)
    o1, s1, r1, d1, i1 = view.step(jax.random.key(3), state, actions)
    o2, s2, r2, c2, term, trunc, i2 = view.step_safe(jax.random.key(3), state, actions)
    for a in view.agents:
        np.testing.assert_array_equal(o1[a], o2[a])
        assert r1[a] == r2[a] and c2[a] == i1["cost"][view.agents.index(a)]
        assert bool(d1[a]) == bool(term[a] | trunc[a])
    assert bool(d1["__all__"]) == bool(term["__all__"] | trunc["__all__"])
    assert set(i1["terminal_obs"]) == set(view.agents)
    # an episode that ends resets to the given reset_state, keeping the terminal observation
    st = state
    for t in range(40):
        o, st_next, r, d, info = view.step(jax.random.key(t), st, actions, reset_state=state)
        if bool(d["__all__"]):
            break
        st = st_next
    assert bool(d["__all__"])
    for a in view.agents:
        np.testing.assert_array_equal(o[a], obs[a])  # the reset_state's observation
        np.testing.assert_array_equal(st_next.terminal_obs[a], info["terminal_obs"][a])
    # step_env never resets
    _, st_env, _, d_env, _ = view.step_env(jax.random.key(0), st, actions)
    assert bool(d_env["__all__"]) and int(st_env.step) == int(st.step) + 1


def test_jaxmarl_bad_input_eager_and_under_jit():
    view = JaxMARLDrivingEnv(short("merge"))
    _, state = view.reset(jax.random.key(0))
    key = jax.random.key(1)
    ok = {"agent_0": jnp.int32(1), "agent_1": jnp.int32(1)}
    for actions, match in [({"agent_0": 1}, "missing \\['agent_1'\\]"),
                           ({**ok, "agent_2": 1}, "unknown \\['agent_2'\\]"),
                           ({**ok, "agent_1": 5}, "agent_1 must be an integer in 0..4"),
                           ({**ok, "agent_1": 1.5}, "dtype float"),
                           ({**ok, "agent_1": jnp.array([1, 2])}, "shape"),
                           ([1, 1], "must be a dict")]:
        with pytest.raises(ValueError, match=match):
            view.step(key, state, actions)
    jitted = jax.jit(view.step)
    with pytest.raises(ValueError, match="agent_1 must be an integer.*traced float32"):
        jitted(key, state, {**ok, "agent_1": jnp.float32(1.0)})
    with pytest.raises(ValueError, match="missing"):
        jitted(key, state, {"agent_0": jnp.int32(1)})
    cont = JaxMARLDrivingEnv(short("racetrack"))
    _, cstate = cont.reset(jax.random.key(0))
    zero = jnp.zeros(1, jnp.float32)
    with pytest.raises(ValueError, match="finite"):
        cont.step(key, cstate, {"agent_0": jnp.array([jnp.nan]), "agent_1": zero})
    with pytest.raises(ValueError, match="traced int32"):
        jax.jit(cont.step)(key, cstate, {"agent_0": jnp.array([1]), "agent_1": zero})


@pytest.mark.parametrize("name", [pytest.param("merge", marks=pytest.mark.slow), "racetrack"])  # one default
def test_jaxmarl_ippo_baseline_trains_on_a_scenario(name):
    """JaxMARL's IPPO-FF (examples/jaxmarl_ippo.py) runs a few updates, jitted, on a discrete and a continuous task."""
    sys.path.insert(0, EXAMPLES)
    try:
        import jaxmarl_ippo
    finally:
        sys.path.remove(EXAMPLES)
    config = {**jaxmarl_ippo.CONFIG, "NUM_ENVS": 4, "NUM_STEPS": 16, "TOTAL_TIMESTEPS": 3 * 16 * 4,
              "NUM_MINIBATCHES": 2, "UPDATE_EPOCHS": 2}
    env = JaxMARLDrivingEnv(short(name))
    train = jax.jit(jaxmarl_ippo.make_train(config, env=env))
    out = jax.device_get(train(jax.random.key(0)))
    metrics = out["metrics"]
    assert metrics["total_loss"].shape == (3,)
    assert all(np.all(np.isfinite(v)) for v in jax.tree.leaves(metrics))
    assert np.all(metrics["returned_episode"] > 0)  # episodes ended inside every update (3 s episodes)
    params0 = jaxmarl_ippo.ActorCritic(
        env.action_space("agent_0").n if env.spec.discrete else env.spec.action_dim,
        discrete=env.spec.discrete).init(jax.random.split(jax.random.key(0))[1], jnp.zeros(env.spec.obs_size))
    moved = jax.tree.map(lambda a, b: float(np.abs(np.asarray(a) - np.asarray(b)).max()),
                         out["runner_state"][0].params, params0)
    assert max(jax.tree.leaves(moved)) > 0  # the updates changed the network


# traffic tasks: few vehicles and episodes of at most 6 steps (racetrack decides 5 times a second), so that a short
# rollout crosses auto-resets
TASKS = {"highway-fast-v0-K2": ("highway-fast-v0", {"controlled_vehicles": 2, "vehicles_count": 3, "duration": 3}),
         "racetrack-v0": ("racetrack-v0", {"other_vehicles": 1, "duration": 1}),
         "intersection-multi-agent-v0": ("intersection-multi-agent-v0", {"initial_vehicle_count": 3, "duration": 3})}


@functools.lru_cache(maxsize=None)
def task(name: str):
    return envs_jax.make(TASKS[name][0], **TASKS[name][1])


def _task_rollout_matches(name: str, n: int = 2, steps: int = 8):
    """The view vmapped in one jitted scan equals the simulator's step with JaxMARL's auto-reset written out."""
    env = task(name)
    view = JaxMARLDrivingEnv(env, world_state=True)
    k = env.num_agents
    assert view.observation_space("agent_0").shape == tuple(env.obs_shape[1:])
    assert view.world_state_size == k * int(np.prod(env.obs_shape[1:]))

    def core_step(key, state, action):  # JaxMARL's MultiAgentEnv.step: step with one key, reset with the other
        key_step, key_reset = jax.random.split(key)
        obs, st, reward, cost, done, info = env.step(key_step, state, action)
        obs_re, st_re = env.reset(key_reset)
        st = jax.tree.map(lambda a, b: jnp.where(done, a, b), st_re, st)
        return jnp.where(done, obs_re, obs), st, reward, cost, done, info

    @jax.jit
    def run(key):
        k_reset, k_run = jax.random.split(key)
        resets = jax.random.split(k_reset, n)
        obs_v, st_v = jax.vmap(view.reset)(resets)
        obs_c, st_c = jax.vmap(env.reset)(resets)
        same0 = jnp.array_equal(jnp.stack([obs_v[a] for a in view.agents], 1), obs_c)

        def body(carry, key):
            st_v, st_c = carry
            k_act, k_step = jax.random.split(key)
            keys = jax.random.split(k_act, k)
            actions = {a: jax.vmap(view.action_space(a).sample)(jax.random.split(keys[i], n))
                       for i, a in enumerate(view.agents)}
            stacked = jnp.stack([actions[a] for a in view.agents], axis=1)
            keys_step = jax.random.split(k_step, n)
            obs_v, st_v, rew_v, done_v, info_v = jax.vmap(view.step)(keys_step, st_v, actions)
            obs_c, st_c, rew_c, cost_c, done_c, info_c = jax.vmap(core_step)(keys_step, st_c, stacked)
            out = {"obs_v": jnp.stack([obs_v[a] for a in view.agents], 1), "obs_c": obs_c,
                   "world_v": obs_v["world_state"], "world_c": obs_c.reshape(n, -1),
                   "rew_v": jnp.stack([rew_v[a] for a in view.agents], 1), "rew_c": rew_c,
                   "cost_v": info_v["cost"], "cost_c": cost_c, "done_v": done_v["__all__"], "done_c": done_c,
                   "agent_done_v": jnp.stack([done_v[a] for a in view.agents], 1),
                   "agent_done_c": info_c["terminated"] | info_c["truncated"][:, None],
                   "info_shapes": jnp.stack([jnp.asarray(v.shape[1:] == (k,)) for v in jax.tree.leaves(info_v)])}
            return (st_v, st_c), out

        _, out = jax.lax.scan(body, (st_v, st_c), jax.random.split(k_run, steps))
        return same0, out

    same0, out = jax.device_get(run(jax.random.key(3)))
    assert same0
    for a, b in [("obs_v", "obs_c"), ("world_v", "world_c"), ("rew_v", "rew_c"), ("cost_v", "cost_c"),
                 ("done_v", "done_c"), ("agent_done_v", "agent_done_c")]:
        np.testing.assert_array_equal(out[a], out[b], err_msg=f"{a} != {b}")
    assert out["done_c"].sum() >= n  # 3 s episodes: every run auto-reset
    assert out["info_shapes"].all()  # every info leaf [K], reward terms included; slot-level ones left out


def test_jaxmarl_view_on_a_traffic_task_matches_the_simulator_under_jit_and_vmap():
    _task_rollout_matches("highway-fast-v0-K2")


@pytest.mark.slow
@pytest.mark.parametrize("name", ["racetrack-v0", "intersection-multi-agent-v0"])
def test_jaxmarl_view_on_more_traffic_tasks_matches_the_simulator(name):
    _task_rollout_matches(name)


@pytest.mark.slow
def test_jaxmarl_ippo_baseline_trains_on_a_traffic_task():
    """JaxMARL's IPPO-FF on highway (K = 2, [5, 5] observations flattened by batchify)."""
    sys.path.insert(0, EXAMPLES)
    try:
        import jaxmarl_ippo
    finally:
        sys.path.remove(EXAMPLES)
    config = {**jaxmarl_ippo.CONFIG, "NUM_ENVS": 4, "NUM_STEPS": 16, "TOTAL_TIMESTEPS": 2 * 16 * 4,
              "NUM_MINIBATCHES": 2, "UPDATE_EPOCHS": 1}
    train = jax.jit(jaxmarl_ippo.make_train(config, env=JaxMARLDrivingEnv(task("highway-fast-v0-K2"))))
    metrics = jax.device_get(train(jax.random.key(0))["metrics"])
    assert metrics["total_loss"].shape == (2,)
    assert all(np.all(np.isfinite(v)) for v in jax.tree.leaves(metrics))
    assert np.all(metrics["returned_episode"] > 0)
