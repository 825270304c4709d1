"""JaxMARL's IPPO baseline (its feed-forward single-file form) on a jaxsmarl scenario.

```
python examples/jaxmarl_ippo.py --scenario merge --timesteps 20000
python examples/jaxmarl_ippo.py --scenario racetrack --timesteps 20000      # continuous actions
```

The training program is JaxMARL's IPPO-FF as published with the library (PureJaxRL's PPO with
independent, parameter-shared actors): the same config keys and defaults, the same
``make_train(config) -> train(rng)`` structure, JaxMARL's own ``LogWrapper`` around the env, the
same ``batchify`` / ``unbatchify`` between agent dicts and ``[num_actors, ...]`` arrays, the
same info reshape to ``[num_actors]``, GAE, clipped value and policy losses, minibatch epochs
and linear learning-rate annealing; the only changes are the env (``JaxMARLDrivingEnv``
instead of ``jaxmarl.make``), no wandb/hydra, and small Categorical / diagonal-Gaussian
distributions written out here instead of importing distrax (a Gaussian policy with a learned
log-std, as JaxMARL's continuous IPPO uses, for the continuous scenarios).
"""

from __future__ import annotations

import argparse
from typing import NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax.linen.initializers import constant, orthogonal
from flax.training.train_state import TrainState
from jaxmarl.environments.spaces import Discrete
from jaxmarl.wrappers.baselines import LogWrapper

import envs_jax
from envs_jax.views import JaxMARLDrivingEnv

CONFIG = {  # JaxMARL's ippo_ff defaults, sized down
    "LR": 2.5e-4, "NUM_ENVS": 16, "NUM_STEPS": 128, "TOTAL_TIMESTEPS": 2e5, "UPDATE_EPOCHS": 4,
    "NUM_MINIBATCHES": 4, "GAMMA": 0.99, "GAE_LAMBDA": 0.95, "CLIP_EPS": 0.2, "ENT_COEF": 0.01,
    "VF_COEF": 0.5, "MAX_GRAD_NORM": 0.5, "ACTIVATION": "tanh", "ANNEAL_LR": True, "ENV_NAME": "merge",
    "ENV_KWARGS": {},
}


class Categorical(NamedTuple):
    logits: jax.Array

    def sample(self, seed):
        return jax.random.categorical(seed, self.logits)

    def log_prob(self, x):
        return jnp.take_along_axis(jax.nn.log_softmax(self.logits), x[..., None], axis=-1)[..., 0]

    def entropy(self):
        logp = jax.nn.log_softmax(self.logits)
        return -jnp.sum(jnp.exp(logp) * logp, axis=-1)


class DiagGaussian(NamedTuple):
    mean: jax.Array
    log_std: jax.Array

    def sample(self, seed):
        return self.mean + jnp.exp(self.log_std) * jax.random.normal(seed, self.mean.shape)

    def log_prob(self, x):
        z = (x - self.mean) / jnp.exp(self.log_std)
        return jnp.sum(-0.5 * z * z - self.log_std - 0.5 * jnp.log(2 * jnp.pi), axis=-1)

    def entropy(self):
        return jnp.sum(self.log_std + 0.5 * (1.0 + jnp.log(2 * jnp.pi)), axis=-1) * jnp.ones(self.mean.shape[:-1])


class ActorCritic(nn.Module):
    """Two tanh layers of 64 for the actor and for the critic, orthogonal init (JaxMARL's IPPO-FF)."""

    action_dim: int
    discrete: bool = True
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x):
        act = nn.relu if self.activation == "relu" else nn.tanh
        dense = lambda n, scale: nn.Dense(n, kernel_init=orthogonal(scale), bias_init=constant(0.0))
        a = act(dense(64, np.sqrt(2))(x))
        a = act(dense(64, np.sqrt(2))(a))
        a = dense(self.action_dim, 0.01)(a)
        if self.discrete:
            pi = Categorical(a)
        else:
            log_std = self.param("log_std", nn.initializers.zeros, (self.action_dim,))
            pi = DiagGaussian(a, jnp.broadcast_to(log_std, a.shape))
        c = act(dense(64, np.sqrt(2))(x))
        c = act(dense(64, np.sqrt(2))(c))
        c = dense(1, 1.0)(c)
        return pi, jnp.squeeze(c, axis=-1)


class Transition(NamedTuple):
    done: jax.Array
    action: jax.Array
    value: jax.Array
    reward: jax.Array
    log_prob: jax.Array
    obs: jax.Array
    info: dict


def batchify(x: dict, agents, num_actors):
    return jnp.stack([x[a] for a in agents]).reshape((num_actors, -1))


def unbatchify(x, agents, num_envs, num_agents):
    x = x.reshape((num_agents, num_envs, -1))
    return {a: x[i] for i, a in enumerate(agents)}


def make_env(config):
    return JaxMARLDrivingEnv(envs_jax.make(config["ENV_NAME"], **config["ENV_KWARGS"]))


def make_train(config, env=None):
    """JaxMARL's IPPO-FF ``make_train``: returns the pure ``train(rng)``."""
    config = dict(config)
    env = make_env(config) if env is None else env
    config["NUM_ACTORS"] = env.num_agents * config["NUM_ENVS"]
    config["NUM_UPDATES"] = int(config["TOTAL_TIMESTEPS"] // config["NUM_STEPS"] // config["NUM_ENVS"])
    config["MINIBATCH_SIZE"] = config["NUM_ACTORS"] * config["NUM_STEPS"] // config["NUM_MINIBATCHES"]
    env = LogWrapper(env)
    space = env.action_space(env.agents[0])
    discrete = isinstance(space, Discrete)
    action_dim = space.n if discrete else int(np.prod(space.shape))

    def linear_schedule(count):
        frac = 1.0 - (count // (config["NUM_MINIBATCHES"] * config["UPDATE_EPOCHS"])) / config["NUM_UPDATES"]
        return config["LR"] * frac

    def train(rng):
        network = ActorCritic(action_dim, discrete=discrete, activation=config["ACTIVATION"])
        rng, _rng = jax.random.split(rng)
        # batchify flattens each agent's observation ([5, 5] Kinematics, [2, 12, 12] grids) for the MLP
        params = network.init(_rng, jnp.zeros(int(np.prod(env.observation_space(env.agents[0]).shape))))
        lr = linear_schedule if config["ANNEAL_LR"] else config["LR"]
        tx = optax.chain(optax.clip_by_global_norm(config["MAX_GRAD_NORM"]), optax.adam(lr, eps=1e-5))
        train_state = TrainState.create(apply_fn=network.apply, params=params, tx=tx)

        rng, _rng = jax.random.split(rng)
        obsv, env_state = jax.vmap(env.reset)(jax.random.split(_rng, config["NUM_ENVS"]))

        def _update_step(runner_state, unused):
            def _env_step(runner_state, unused):
                train_state, env_state, last_obs, rng = runner_state
                obs_batch = batchify(last_obs, env.agents, config["NUM_ACTORS"])
                rng, _rng = jax.random.split(rng)
                pi, value = network.apply(train_state.params, obs_batch)
                action = pi.sample(seed=_rng)
                log_prob = pi.log_prob(action)
                env_act = unbatchify(action, env.agents, config["NUM_ENVS"], env.num_agents)
                rng, _rng = jax.random.split(rng)
                obsv, env_state, reward, done, info = jax.vmap(env.step)(
                    jax.random.split(_rng, config["NUM_ENVS"]), env_state, env_act)
                info = jax.tree.map(lambda x: x.reshape((config["NUM_ACTORS"])), info)
                transition = Transition(batchify(done, env.agents, config["NUM_ACTORS"]).squeeze(), action, value,
                                        batchify(reward, env.agents, config["NUM_ACTORS"]).squeeze(), log_prob,
                                        obs_batch, info)
                return (train_state, env_state, obsv, rng), transition

            runner_state, traj_batch = jax.lax.scan(_env_step, runner_state, None, config["NUM_STEPS"])
            train_state, env_state, last_obs, rng = runner_state
            _, last_val = network.apply(train_state.params, batchify(last_obs, env.agents, config["NUM_ACTORS"]))

            def _get_advantages(carry, transition):
                gae, next_value = carry
                delta = transition.reward + config["GAMMA"] * next_value * (1 - transition.done) - transition.value
                gae = delta + config["GAMMA"] * config["GAE_LAMBDA"] * (1 - transition.done) * gae
                return (gae, transition.value), gae

            _, advantages = jax.lax.scan(_get_advantages, (jnp.zeros_like(last_val), last_val), traj_batch,
                                         reverse=True, unroll=8)
            targets = advantages + traj_batch.value

            def _update_epoch(update_state, unused):
                def _update_minbatch(train_state, batch_info):
                    traj, gae, targets = batch_info

                    def _loss_fn(params):
                        pi, value = network.apply(params, traj.obs)
                        log_prob = pi.log_prob(traj.action)
                        value_clipped = traj.value + (value - traj.value).clip(-config["CLIP_EPS"], config["CLIP_EPS"])
                        value_loss = 0.5 * jnp.maximum(jnp.square(value - targets),
                                                       jnp.square(value_clipped - targets)).mean()
                        ratio = jnp.exp(log_prob - traj.log_prob)
                        g = (gae - gae.mean()) / (gae.std() + 1e-8)
                        actor_loss = -jnp.minimum(ratio * g, jnp.clip(ratio, 1.0 - config["CLIP_EPS"],
                                                                      1.0 + config["CLIP_EPS"]) * g).mean()
                        entropy = pi.entropy().mean()
                        total = actor_loss + config["VF_COEF"] * value_loss - config["ENT_COEF"] * entropy
                        return total, (value_loss, actor_loss, entropy)

                    (total, aux), grads = jax.value_and_grad(_loss_fn, has_aux=True)(train_state.params)
                    train_state = train_state.apply_gradients(grads=grads)
                    return train_state, {"total_loss": total, "critic_loss": aux[0], "actor_loss": aux[1],
                                         "entropy": aux[2]}

                train_state, traj_batch, advantages, targets, rng = update_state
                rng, _rng = jax.random.split(rng)
                batch_size = config["MINIBATCH_SIZE"] * config["NUM_MINIBATCHES"]
                assert batch_size == config["NUM_STEPS"] * config["NUM_ACTORS"]
                permutation = jax.random.permutation(_rng, batch_size)
                batch = jax.tree.map(lambda x: x.reshape((batch_size,) + x.shape[2:]),
                                     (traj_batch, advantages, targets))
                shuffled = jax.tree.map(lambda x: jnp.take(x, permutation, axis=0), batch)
                minibatches = jax.tree.map(lambda x: x.reshape([config["NUM_MINIBATCHES"], -1] + list(x.shape[1:])),
                                           shuffled)
                train_state, loss_info = jax.lax.scan(_update_minbatch, train_state, minibatches)
                return (train_state, traj_batch, advantages, targets, rng), loss_info

            update_state, loss_info = jax.lax.scan(_update_epoch, (train_state, traj_batch, advantages, targets, rng),
                                                   None, config["UPDATE_EPOCHS"])
            train_state, rng = update_state[0], update_state[-1]
            metric = jax.tree.map(lambda x: x.mean(), traj_batch.info)
            metric = {**metric, **jax.tree.map(lambda x: x.mean(), loss_info)}
            # mean return of the episodes that ended during this update (per agent-step, as JaxMARL logs it)
            ended = traj_batch.info["returned_episode"]
            metric["episode_return"] = jnp.sum(traj_batch.info["returned_episode_returns"] * ended) / jnp.maximum(
                ended.sum(), 1)
            metric["episode_cost_rate"] = traj_batch.info["cost"].mean()
            return (train_state, env_state, last_obs, rng), metric

        rng, _rng = jax.random.split(rng)
        runner_state, metric = jax.lax.scan(_update_step, (train_state, env_state, obsv, _rng), None,
                                            config["NUM_UPDATES"])
        return {"runner_state": runner_state, "metrics": metric}

    return train


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="merge",
                        choices=envs_jax.available_scenarios() + envs_jax.available_tasks())
    parser.add_argument("--timesteps", type=float, default=CONFIG["TOTAL_TIMESTEPS"])
    parser.add_argument("--num-envs", type=int, default=CONFIG["NUM_ENVS"])
    parser.add_argument("--num-steps", type=int, default=CONFIG["NUM_STEPS"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    config = {**CONFIG, "ENV_NAME": args.scenario, "TOTAL_TIMESTEPS": args.timesteps, "NUM_ENVS": args.num_envs,
              "NUM_STEPS": args.num_steps}
    out = jax.jit(make_train(config))(jax.random.key(args.seed))
    metrics = jax.device_get(out["metrics"])
    for u in range(len(metrics["total_loss"])):
        print(f"update {u:3d}  episode return {metrics['episode_return'][u]:8.2f}  "
              f"cost/step {metrics['episode_cost_rate'][u]:.3f}  loss {metrics['total_loss'][u]:.3f}")
    return metrics


if __name__ == "__main__":
    main()
