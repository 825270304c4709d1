"""merge-cavs-v0 (MARL_CAVs' multi-agent merge): config checks, the per-density counts and spawn rule, the reward
terms against their closed forms on hand-built states, absent slots, jit/vmap, and parity of the road and the IDM
traffic with highway-env's own classes (tests/merge_cavs_oracle.py)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_jax
from envs_jax.scenarios import merge_cavs as MC

DENSITY_RANGES = {1: ((1, 3), (1, 3)), 2: ((2, 4), (2, 4)), 3: ((4, 6), (3, 5))}


@functools.cache
def env_of(density=3, **kw):
    return envs_jax.make("merge-cavs-v0", traffic_density=density, **kw)


@pytest.mark.parametrize("bad", [
    {"traffic_density": 0}, {"traffic_density": 4}, {"traffic_density": "extreme"}, {"traffic_density": True},
    {"traffic_density": 2.0}, {"safety_guarantee": True}, {"action_masking": True}, {"seed": 0},
    {"num_slots": 5}, {"HEADWAY_TIME": 0}, {"reward_speed_range": [10, 10]}, {"collision_cost": -1.0},
    {"idm": {"politeness_x": 1}}, {"observation": {"type": "OccupancyGrid"}}])
def test_bad_config(bad):
    with pytest.raises(ValueError, match="merge-cavs-v0"):
        envs_jax.make("merge-cavs-v0", **bad)


def test_config_accepted():
    """MARL_CAVs' ENV_CONFIG keys as they are, density names, and K = the density's most CAVs."""
    cfg = {"simulation_frequency": 15, "duration": 20, "policy_frequency": 5, "COLLISION_REWARD": 200,
           "HIGH_SPEED_REWARD": 1, "HEADWAY_COST": 4, "HEADWAY_TIME": 1.2, "MERGING_LANE_COST": 4,
           "traffic_density": 2}
    env = envs_jax.make("merge-cavs-v0", cfg)
    assert env.num_agents == 4 and env.num_slots == 8 and env.frames == 3
    for name, k in (("easy", 3), ("medium", 4), ("hard", 6)):
        assert envs_jax.make("merge-cavs-v0", traffic_density=name).num_agents == k
    assert envs_jax.make("merge-cavs-v0", traffic_density=1, num_slots=9).num_slots == 9
    np.testing.assert_allclose(env.default_params.target_speeds, [10, 15, 20, 25, 30])


def test_road_and_obstacle_positions():
    """MARL_CAVs' geometry: ramp at y = 10.5 joining the merge lane at (320, 4), which ends at (420, 4)."""
    env = env_of(1)
    road = env.road
    assert road.lane_names == [("a", "b", 0), ("b", "c", 0), ("b", "c", 1), ("c", "d", 0), ("j", "k", 0),
                               ("k", "b", 0)]
    from envs_jax import lanes as L

    kb = road.lane("k", "b", 0)
    x, y = L.position(road.lanes, jnp.int32(kb), jnp.asarray([0.0, 100.0]), jnp.zeros(2))
    np.testing.assert_allclose(np.c_[x, y], [[220, 10.5], [320, 4]], atol=1e-4)
    np.testing.assert_allclose(env.default_params.obstacles[0, :2], [420, 4], atol=1e-9)


@pytest.mark.parametrize("density", [1, 2, 3])
def test_counts_and_spawn_rule(density):
    """Over many resets: counts within the density's ranges and every count drawn; CAVs in the first slots
    (present ones a prefix), n // 2 of each kind on the main road; every vehicle within 1.5 m of a spawn point,
    no spawn point used twice; speeds in [25, 27] m/s."""
    env = env_of(density)
    K = env.num_agents
    (c_lo, c_hi), (h_lo, h_hi) = DENSITY_RANGES[density]
    assert K == c_hi and env.num_slots == c_hi + h_hi
    spawn = jax.jit(jax.vmap(lambda k: env.task.initial_vehicles(k, env.default_params)))
    st = spawn(jax.random.split(jax.random.key(density), 400))
    alive = np.asarray(st["alive"])
    x, y, v = (np.asarray(st[k], np.float64) for k in ("x", "y", "speed"))
    n_cav, n_hdv = alive[:, :K].sum(1), alive[:, K:].sum(1)
    assert set(n_cav) == set(range(c_lo, c_hi + 1))
    assert set(n_hdv) == set(range(h_lo, h_hi + 1))
    prefix = lambda a, n: np.array_equal(a, np.arange(a.shape[0]) < n)
    for e in range(len(alive)):
        assert prefix(alive[e, :K], n_cav[e]) and prefix(alive[e, K:], n_hdv[e])
        for part, n in ((slice(0, K), n_cav[e]), (slice(K, None), n_hdv[e])):
            ys = y[e, part][:n]
            assert np.array_equal(ys, np.where(np.arange(n) < n // 2, 0.0, MC.RAMP_Y))
        a = alive[e]
        for road_y, spawns in ((0.0, MC.MAIN_SPAWNS), (MC.RAMP_Y, MC.RAMP_SPAWNS)):
            xs = x[e, a & (y[e] == road_y)]
            nearest = np.argmin(np.abs(xs[:, None] - np.asarray(spawns)[None]), axis=1)
            assert np.all(np.abs(xs - np.asarray(spawns)[nearest]) <= 1.5 + 1e-5)
            assert len(set(nearest)) == len(xs)
        assert np.all((v[e, a] >= 25 - 1e-5) & (v[e, a] <= 27 + 1e-5))


def state_with(env, vehicles, agents_present):
    """A state from ``vehicles``: slot -> (x, y, speed); the other slots empty."""
    V = env.num_slots
    init = {k: np.zeros(V) for k in ("x", "y", "heading", "speed")}
    init["alive"] = np.zeros(V, bool)
    init["delta"] = np.full(V, 4.0)
    for slot, (x, y, v) in vehicles.items():
        init["x"][slot], init["y"][slot], init["speed"][slot] = x, y, v
        init["alive"][slot] = True
    assert [bool(init["alive"][k]) for k in range(env.num_agents)] == agents_present
    return jax.jit(env.state_from)(init, env.default_params)[1]


@functools.cache
def outcome_fn(env):
    return jax.jit(lambda st: env.task.outcome(st, st, jnp.ones(env.num_agents, jnp.int32), env.default_params))


def outcome(env, st):
    r, c, term, info = outcome_fn(env)(st)
    return np.asarray(r, np.float64), np.asarray(c), np.asarray(term), info


def speed_term(v):
    return min(max((v - 10) / 20, 0), 1)


def test_reward_closed_forms():
    """Headway on the own lane and on the next lane, the 60 m cap, the merging-lane term, speed 0 and the
    absent agent, each against ``-200 crashed + clip(lmap(v)) + 4 m + 4 min(0, log(h / (1.2 v)))``."""
    env = env_of(1)  # agents 0..2, HDV slots 3..5
    st = state_with(env, {
        0: (100.0, 0.0, 20.0),  # main road, an HDV 20 m ahead on its lane
        3: (120.0, 0.0, 25.0),
        1: (310.0, 0.0, 24.0),  # end of a->b: the next lane b->c 0 has a vehicle 20 m ahead;
        4: (330.0, 0.0, 25.0),  # the merge lane's vehicle (b->c 1, 12 m ahead) is not on its next lane
        5: (322.0, 4.0, 25.0),
        2: (400.0, 4.0, 30.0),  # merge lane: nothing ahead on it (the next-lane rule does not apply)
    }, [True, True, True])
    r, c, term, info = outcome(env, st)
    lane = np.asarray(st.lane)
    assert [env.road.lane_names[i] for i in lane[:6]] == [("a", "b", 0), ("a", "b", 0), ("b", "c", 1),
                                                         ("a", "b", 0), ("b", "c", 0), ("b", "c", 1)]
    np.testing.assert_allclose(np.asarray(info["rewards"]["headway"]), [20.0, 20.0, 60.0], rtol=1e-6)
    expect = [speed_term(20) + 4 * np.log(20 / (1.2 * 20)),
              speed_term(24) + 4 * np.log(20 / (1.2 * 24)),
              speed_term(30) + 4 * -np.exp(-(400 - 420) ** 2 / 1000)]  # log(60 / 36) > 0: no headway cost
    np.testing.assert_allclose(r, expect, rtol=1e-5)
    np.testing.assert_array_equal(c, 0)
    assert not term.any()

    # one agent absent, one at a standstill (no headway term) close behind another
    st = state_with(env, {0: (200.0, 10.5, 0.0), 1: (205.0, 10.5, 12.0), 3: (50.0, 0.0, 26.0)},
                    [True, True, False])
    r, c, term, info = outcome(env, st)
    np.testing.assert_allclose(r, [0.0, speed_term(12), 0.0], atol=1e-6)
    np.testing.assert_array_equal(term, [False, False, True])
    np.testing.assert_array_equal(np.asarray(info["alive"]), [True, True, False])
    np.testing.assert_allclose(float(info["average_speed"]), 6.0, rtol=1e-6)


@functools.cache
def batched():
    """One density-3 env with absolute, unnormalised observations that see behind, and its jit(vmap) reset and
    step (shared by the tests below, so compiled once)."""
    env = envs_jax.make("merge-cavs-v0", traffic_density=3, observation={
        "type": "Kinematics", "absolute": True, "normalize": False, "see_behind": True, "vehicles_count": 12})
    return env, jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))


def test_crash_reward_cost_and_termination():
    """Two agents driven into each other: -200 and the collision cost for both, every agent terminated (the
    episode ends at the first crash), nothing for the absent agents."""
    env, _, step = batched()
    present = [True, True, False, False, False, False]
    st = state_with(env, {0: (100.0, 0.0, 30.0), 1: (104.0, 0.0, 10.0), 6: (250.0, 0.0, 25.0)}, present)
    batch = lambda a: jnp.stack([a, a])
    _, st2, r, c, done, info = step(jax.random.split(jax.random.key(0), 2), jax.tree.map(batch, st),
                                    jnp.ones((2, 6), jnp.int32))
    r, c, st2 = np.asarray(r[0], np.float64), np.asarray(c[0]), jax.tree.map(lambda a: a[0], st2)
    np.testing.assert_array_equal(np.asarray(info["crashed"][0]), [True, True, False, False, False, False])
    v = np.asarray(st2.speed, np.float64)[:2]
    xs = np.asarray(st2.x, np.float64)
    others = xs[np.asarray(st2.alive)]  # all on a->b
    hw = [min([60.0] + [o - xs[k] for o in others if o > xs[k]]) for k in range(2)]
    expect = [-200 + speed_term(vk) + (4 * min(0.0, np.log(h / (1.2 * vk))) if vk > 0 else 0.0)
              for vk, h in zip(v, hw)]
    np.testing.assert_allclose(r[:2], expect, rtol=1e-5)
    np.testing.assert_array_equal(r[2:], 0.0)
    np.testing.assert_array_equal(c, [5.0, 5.0, 0, 0, 0, 0])
    np.testing.assert_array_equal(np.asarray(info["terminated"][0]), True)
    assert bool(done[0])


def test_absent_slots_never_collide_or_appear():
    """Random-action episodes (jit of vmap): absent slots (all parked at the same point, so they would collide
    with each other if checked) never crash or move, every observed row is a present vehicle or the obstacle, an
    absent agent observes zeros and gets reward and cost 0; ``info["alive"]`` is the agents' slots' flag."""
    env, reset, step = batched()
    E, T, K = 2, 10, env.num_agents
    obs, st = reset(jax.random.split(jax.random.key(3), E))
    alive0 = np.asarray(st.alive)
    dead = ~alive0
    assert dead.sum() >= E  # density 3: 11 slots, at most 10 vehicles
    np.testing.assert_array_equal(np.asarray(MC.agents_alive(env, st)), alive0[:, :K])
    rng = np.random.default_rng(4)
    pos_obstacle = env.default_params.obstacles[:, :2]
    for t in range(T + 1):
        if t:
            keys = jax.random.split(jax.random.key(100 + t), E)
            obs, st, r, c, _, info = step(keys, st, jnp.asarray(rng.integers(0, 5, (E, K)), jnp.int32))
            np.testing.assert_array_equal(np.asarray(info["alive"]), alive0[:, :K])
            assert np.all(np.asarray(r)[dead[:, :K]] == 0) and np.all(np.asarray(c)[dead[:, :K]] == 0)
        x, y, crashed, o_all = (np.asarray(a) for a in (st.x, st.y, st.crashed, obs))
        assert not crashed[dead].any() and np.all(x[dead] == 0)
        for e in range(E):
            pos = np.vstack([np.c_[x[e], y[e]][alive0[e]], pos_obstacle])
            for k in range(K):
                o = o_all[e, k]
                if not alive0[e, k]:
                    assert not o.any()
                    continue
                rows = o[o[:, 0] > 0][:, 1:3]
                assert len(rows) >= 1
                assert np.all(np.abs(rows[:, None, :] - pos[None]).max(-1).min(1) < 1e-3), (e, t, k)


def check_parity(density, seed, steps):
    """One random-action episode in both simulators, everything asserted; returns (steps, lane-change decisions,
    crashed vehicles at the end)."""
    from tests.merge_cavs_oracle import cavs_drivers
    from tests.traffic_oracle import oracle_config, run_oracle
    from tests.traffic_utils import run_jax

    name = "merge-cavs-v0"
    env = env_of(density)
    actions = np.random.default_rng(seed).integers(0, 5, size=(steps, env.num_agents))
    j = run_jax(name, seed, actions, traffic_density=density)
    alive = j["init"]["alive"]
    present = alive[: env.num_agents]
    controlled = tuple(int(i) for i in np.nonzero(present)[0])
    with cavs_drivers():
        o = run_oracle(name, j["init"], controlled, actions[: j["length"]][:, present],
                       oracle_config(name, len(controlled)))
    assert len(o["frames"]["x"]) == j["length"] * env.frames
    for key in ("x", "y", "heading", "speed"):
        np.testing.assert_allclose(j["frames"][key][:, alive], o["frames"][key], rtol=0, atol=1e-6, err_msg=key)
    for key in ("crashed", "lane", "target_lane"):
        np.testing.assert_array_equal(j["frames"][key][:, alive], o["frames"][key], err_msg=key)
    np.testing.assert_allclose(j["obs"][:, present].astype(np.float32), o["obs"], rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(j["reward"][:, present], o["reward"], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(j["terminated"][:, present], o["terminated"])
    tl = o["frames"]["target_lane"]
    return j["length"], int((tl[1:] != tl[:-1]).sum()), int(o["frames"]["crashed"][-1].sum())


def test_parity_with_highway_env(x64):
    """An episode of random actions against highway-env's own vehicles on MARL_CAVs' road (built from
    highway-env's lane classes) with MARL_CAVs' driver constants: every vehicle's pose every frame, lanes,
    crashes, observations, per-agent rewards and terminations."""
    _, changes, _ = check_parity(2, 7, 15)
    assert changes > 0


@pytest.mark.slow
@pytest.mark.parametrize("density", [1, 2, 3])
def test_parity_full(density, x64):
    """Ten random-action episodes per density, up to 40 decisions (8 s) or the first crash."""
    total = [check_parity(density, 200 + seed, 40) for seed in range(10)]
    steps, changes, crashes = (sum(t[i] for t in total) for i in range(3))
    print(f"\nmerge-cavs-v0 density {density}: 10 episodes, {steps} steps, {changes} lane-change decisions, "
          f"{crashes} vehicles crashed at the end")


def test_train_config():
    """``--scenario merge-cavs``: K = 3 (easy traffic) by default or 4 (medium); other K refused by name."""
    from train.config import load_config

    assert load_config("merge-cavs", "csq")["agents"] == 3
    cfg = load_config("merge-cavs", "csq", {"agents": 4, "hierarchy": "0,1|2,3"})
    assert cfg["agents"] == 4 and cfg["hierarchy"] == "0,1|2,3"
    for k in (2, 5, 6):
        with pytest.raises(ValueError, match="'agents' for scenario 'merge-cavs' must be 3..4"):
            load_config("merge-cavs", "csq", {"agents": k})


@pytest.mark.slow
def test_csq_trains_on_merge_cavs():
    """CSQ with one leader and two followers through the off-policy loop and the greedy evaluation on easy traffic
    (1-3 CAVs an episode): finite losses, and agent 0 (present in every episode) returns its reward."""
    from train.build import make_train
    from train.config import load_config
    from train.trainer import seed_keys

    cfg = load_config("merge-cavs", "csq", {"agents": 3, "hierarchy": "0|1,2", "total_steps": 120, "num_envs": 2,
                                            "chunk_steps": 120, "num_seeds": 1, "warmup": 16, "batch_size": 16,
                                            "checkpoint_every": 0, "eval_episodes": 2, "eval_max_steps": 100})
    trainer = make_train(cfg)
    assert trainer.env.name == "merge-cavs-v0" and trainer.env.num_agents == 3
    state, m = jax.jit(trainer.train)(seed_keys(cfg)[0])
    loss = np.asarray(m["update"]["loss_q"])
    assert loss.shape == (60, 3) and np.all(np.isfinite(loss))
    rec = jax.jit(trainer.evaluate)(state.agent, jax.random.PRNGKey(0))
    assert np.all(np.asarray(rec["returned"])) and np.all(np.asarray(rec["leader_return"]) != 0)


def test_csq_loss_leaves_absent_agents_out():
    """With ``absent_agents`` each agent's critic losses (and mean predictions) are those of the plain loss on the
    transitions where that agent is present."""
    from jaxsmarl.algos.csq import CSQAgent, CSQConfig

    n, B, D = 3, 8, 4
    kw = {"num_actions": (5,) * n, "obs_dim": D, "hidden_sizes": (8,), "cost_threshold": (5.0,) * n,
          "eps_start": (0.1,) * n, "eps_min": (0.0,) * n}
    masked, plain = CSQAgent(CSQConfig(absent_agents=True, **kw)), CSQAgent(CSQConfig(**kw))
    params = jax.jit(plain.init)(jax.random.key(0)).params
    ks = jax.random.split(jax.random.key(1), 3)
    active = np.ones((B, n), bool)  # each agent present in 5 of the 8 transitions (one compiled plain loss)
    active[5:, 0] = False
    active[:3, 1] = False
    active[[0, 3, 6], 2] = False
    batch = masked.Transition(obs=jax.random.normal(ks[0], (B, n, D)), action=jax.random.randint(ks[1], (B, n), 0, 5),
                              reward=jnp.zeros((B, n)), cost=jnp.zeros((B, n)), next_obs=jnp.zeros((B, n, D)),
                              terminated=jnp.zeros((B, n), bool), truncated=jnp.zeros((B,), bool),
                              active=jnp.asarray(active))
    targets = jax.random.normal(ks[2], (B, n, 2))
    _, (per_net, mean_pred) = jax.jit(masked.loss)(params, batch, targets)
    plain_loss = jax.jit(plain.loss)
    for k in range(n):
        rows = np.nonzero(active[:, k])[0]
        sub = plain.Transition(**{f: getattr(batch, f)[rows] for f in plain.Transition.__dataclass_fields__})
        _, (ref, ref_pred) = plain_loss(params, sub, targets[rows])
        np.testing.assert_allclose(np.asarray(per_net[k]), np.asarray(ref[k]), rtol=1e-5)
        np.testing.assert_allclose(np.asarray(mean_pred[k]), np.asarray(ref_pred[k]), rtol=1e-5, atol=1e-7)
    assert masked.transition_example().active.shape == (n,) and not hasattr(plain.transition_example(), "active")
