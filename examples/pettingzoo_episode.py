"""A PettingZoo episode of a jaxsmarl scenario with random actions, the safe 6-tuple and a frame.

```
python examples/pettingzoo_episode.py --scenario roundabout --frame frame.png
python examples/pettingzoo_episode.py --scenario intersection-multi-agent-v0 --frame frame.png   # a traffic task
```
"""

from __future__ import annotations

import argparse

import envs_jax
from envs_jax.views import PettingZooDrivingEnv


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="merge",
                        choices=envs_jax.available_scenarios() + envs_jax.available_tasks())
    parser.add_argument("--duration", type=float, default=None,
                        help="episode length in seconds (default: the task's)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--frame", default=None, help="save the last frame as this PNG")
    args = parser.parse_args(argv)
    overrides = {} if args.duration is None else {"duration": args.duration}
    env = PettingZooDrivingEnv(envs_jax.make(args.scenario, **overrides), render_mode="rgb_array", safe=True)
    observations, infos = env.reset(seed=args.seed)
    for agent in env.possible_agents:
        env.action_space(agent).seed(args.seed)
    returns = {a: 0.0 for a in env.possible_agents}
    costs = dict(returns)
    steps = 0
    while env.agents:
        actions = {a: env.action_space(a).sample() for a in env.agents}
        observations, rewards, step_costs, terminations, truncations, infos = env.step(actions)
        for a in rewards:
            returns[a] += rewards[a]
            costs[a] += step_costs[a]
        steps += 1
    frame = env.render()
    print(f"{args.scenario}: {steps} steps, returns {returns}, costs {costs}, frame {frame.shape}")
    if args.frame:
        from PIL import Image

        Image.fromarray(frame).save(args.frame)
    return {"steps": steps, "returns": returns, "costs": costs}


if __name__ == "__main__":
    main()
