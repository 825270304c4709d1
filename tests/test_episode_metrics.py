"""Per-agent episode metrics of the K-agent traffic scenarios (jaxsmarl.metrics.episode_record on the traffic
auto-reset wrapper): each agent's return and cost and the average speed, against sums kept step by step in
Python from the unwrapped environment's own outputs."""

import jax
import jax.numpy as jnp
import numpy as np

import envs_jax
from envs_jax.traffic_autoreset import TrafficAutoResetWrapper
from jaxsmarl import metrics


def test_agent_returns_costs_and_speed_match_step_by_step_sums():
    """One merge-v0 episode with 3 agents, stepped by the bare environment and by the wrapper side by side: at the
    end each agent's return and cost are the sums of its rewards and costs, and the speed is the mean over the
    agent-steps driven (agents present and not yet terminated at the step's start, with their speed after it)."""
    env = envs_jax.make("merge-v0", controlled_vehicles=3, duration=30.0)
    wrapped = TrafficAutoResetWrapper(env)
    params = env.default_params
    env_step, wrapped_step = jax.jit(env.step), jax.jit(wrapped.step)
    idx = np.asarray(env.controlled)
    key = jax.random.PRNGKey(7)
    _, wst = wrapped.reset(key, params)
    est = wst.env_state
    ret, cost = np.zeros(3), np.zeros(3)
    speed_sum, steps, terminated = 0.0, 0, np.zeros(3, bool)
    for t in range(40):
        ka = jax.random.fold_in(key, t)
        action = jnp.asarray([t % 5, (t + 2) % 5, 1])
        ks = jax.random.split(ka)[0]  # the wrapper steps the env with the first half of its key
        _, est_next, reward, c, done, info = env_step(ks, est, action, params)
        ret += np.asarray(reward, np.float64)
        cost += np.asarray(c, np.float64)
        drove = np.asarray(est.alive)[idx] & ~terminated
        speed_sum += float(np.sum(np.where(drove, np.asarray(est_next.speed)[idx], 0.0)))
        steps += int(drove.sum())
        terminated |= np.asarray(info["terminated"])
        _, wst, _, _, wdone, winfo = wrapped_step(ka, wst, action, params)
        assert bool(wdone) == bool(done)
        est = est_next
        if bool(done):
            rec = {k: np.asarray(v) for k, v in metrics.episode_record(winfo).items()}
            np.testing.assert_allclose([rec[f"return_{k}"] for k in range(3)], ret, rtol=1e-5, atol=1e-4)
            np.testing.assert_allclose([rec[f"cost_{k}"] for k in range(3)], cost, rtol=1e-6)
            np.testing.assert_allclose(rec["total_return"], ret.sum(), rtol=1e-5, atol=1e-4)
            np.testing.assert_allclose(rec["speed"], speed_sum / steps, rtol=1e-5)
            assert steps >= 3 and cost.sum() > 0  # a crash in this episode: the cost sums are not all zero
            return
    raise AssertionError("episode did not end in 40 steps")


def test_two_agent_scenarios_keep_their_columns():
    env = envs_jax.make("merge")
    wrapped = envs_jax.AutoResetWrapper(env)
    p = env.default_params

    def first_record():
        _, st = wrapped.reset(jax.random.PRNGKey(0), p)
        return metrics.episode_record(wrapped.step(jax.random.PRNGKey(1), st, jnp.asarray([1, 1]), p)[5])

    assert metrics.record_fields(jax.eval_shape(first_record)) == metrics.EPISODE_FIELDS
    assert metrics.record_fields(["speed", "return_0", "return_1", "cost_0", "cost_1"] + list(metrics.EPISODE_FIELDS)) \
        == metrics.EPISODE_FIELDS + metrics.agent_fields(2)
