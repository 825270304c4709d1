"""One agent of a jaxsmarl scenario in Gymnasium (partner idle), then a vector env of the same task.

```
python examples/gymnasium_single_agent.py --scenario racetrack --num-envs 64
python examples/gymnasium_single_agent.py --scenario highway-fast-v0      # a single-agent task: no partner
```
"""

from __future__ import annotations

import argparse

import numpy as np

import envs_jax
from envs_jax.views import GymnasiumDrivingEnv, GymnasiumVectorDrivingEnv, idle_policy


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="racetrack",
                        choices=envs_jax.available_scenarios() + envs_jax.available_tasks())
    parser.add_argument("--duration", type=float, default=None,
                        help="episode length in seconds (default: the task's)")
    parser.add_argument("--agent", type=int, default=0)
    parser.add_argument("--num-envs", type=int, default=16)
    parser.add_argument("--vector-steps", type=int, default=20)
    args = parser.parse_args(argv)
    base = envs_jax.make(args.scenario, **({} if args.duration is None else {"duration": args.duration}))
    partner = idle_policy(base) if base.num_agents > 1 else None  # a single-agent task needs none
    env = GymnasiumDrivingEnv(base, agent=args.agent, partner_policy=partner, safe=True)
    obs, info = env.reset(seed=0)
    env.action_space.seed(0)
    ret = cost = 0.0
    terminated = truncated = False
    steps = 0
    while not (terminated or truncated):
        obs, reward, c, terminated, truncated, info = env.step(env.action_space.sample())
        ret, cost, steps = ret + reward, cost + c, steps + 1
    print(f"{args.scenario} agent {args.agent}: {steps} steps, return {ret:.2f}, cost {cost:.2f}")
    envs = GymnasiumVectorDrivingEnv(base, args.num_envs, agent=args.agent, partner_policy=partner)
    obs, infos = envs.reset(seed=0)
    envs.action_space.seed(0)
    total_cost = 0.0
    for _ in range(args.vector_steps):
        obs, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())
        total_cost += float(np.sum(infos["cost"][infos["_cost"]]))
    print(f"vector env: {args.num_envs} envs x {args.vector_steps} steps, obs {obs.shape}, cost {total_cost:.1f}")
    return {"steps": steps, "return": ret, "cost": cost}


if __name__ == "__main__":
    main()
