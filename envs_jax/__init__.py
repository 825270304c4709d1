"""Pure-JAX two-agent driving simulator reproducing highway-env (merge, roundabout, ...).

>>> import jax, envs_jax
>>> env = envs_jax.make("merge")
>>> obs, state = env.reset(jax.random.key(0), env.default_params)
>>> obs, state, reward, cost, done, info = env.step(jax.random.key(1), state, jax.numpy.array([1, 1]),
...                                                env.default_params)
"""

from envs_jax.env import DrivingEnv, EnvParams, EnvState
from envs_jax.registry import available_scenarios, available_tasks, make, register, register_task
from envs_jax.scenarios.highway import make_highway
from envs_jax.scenarios.intersection import Intersection
from envs_jax.scenarios.intersection_agents import make_intersection_agents
from envs_jax.scenarios.intersection_continuous import make_intersection_continuous
from envs_jax.scenarios.intersection_traffic import make_intersection
from envs_jax.scenarios.merge import Merge
from envs_jax.scenarios.merge_agents import make_merge_agents
from envs_jax.scenarios.merge_cavs import make_merge_cavs
from envs_jax.scenarios.merge_traffic import make_merge
from envs_jax.scenarios.racetrack import Racetrack
from envs_jax.scenarios.racetrack_agents import make_racetrack_agents
from envs_jax.scenarios.racetrack_traffic import make_racetrack
from envs_jax.scenarios.roundabout import Roundabout
from envs_jax.scenarios.roundabout_agents import make_roundabout_agents
from envs_jax.scenarios.roundabout_traffic import make_roundabout
from envs_jax.wrappers import AutoResetWrapper, rollout

register("merge", Merge)
register("roundabout", Roundabout)
register("intersection", Intersection)
register("racetrack", Racetrack)
register_task("highway-v0", make_highway)
register_task("highway-fast-v0", make_highway)
register_task("merge-v0", make_merge)
register_task("merge-k", make_merge_agents)
register_task("merge-cavs-v0", make_merge_cavs)
register_task("roundabout-v0", make_roundabout)
register_task("roundabout-k", make_roundabout_agents)
register_task("racetrack-v0", make_racetrack)
register_task("racetrack-k", make_racetrack_agents, takes_action_mode=True)
register_task("intersection-v0", make_intersection)
register_task("intersection-multi-agent-v0", make_intersection)
register_task("intersection-v1", make_intersection_continuous)
register_task("intersection-k", make_intersection_agents, takes_action_mode=True)

__all__ = ["make", "available_scenarios", "available_tasks", "register", "register_task", "DrivingEnv", "EnvParams",
           "EnvState", "AutoResetWrapper", "rollout"]
