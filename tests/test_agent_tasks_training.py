"""``python -m train --scenario S --agents K`` for the authors' four scenarios: K >= 3 builds the K-agent task
behind the traffic wrapper, K = 2 (or no ``--agents``) the two-agent scenario, and K outside 2..8 is refused."""

import pytest

import envs_jax
from envs_jax.traffic_autoreset import TrafficAutoResetWrapper


# (scenario, algorithm, K, its view, the most agents the algorithm takes: CSQ's grid stops at 5^4)
@pytest.mark.parametrize("scenario, algo, k, obs_shape, most", [
    ("merge", "csq", 3, (3, 12), 4), ("roundabout", "csq", 3, (3, 12), 4),
    ("intersection", "cs-maddpg", 4, (4, 16), 8), ("racetrack", "cs-maddpg", 3, (3, 12), 8),
])
def test_training_builds_the_k_agent_task(scenario, algo, k, obs_shape, most):
    from train.config import validate
    from train.trainer import make_env

    env, wrapped, params = make_env(scenario, k)
    assert env.name == f"{scenario}-k" and env.num_agents == k and wrapped.obs_shape == obs_shape
    assert isinstance(wrapped, TrafficAutoResetWrapper) and params is env.default_params
    for agents in (None, 2):
        env, wrapped, _ = make_env(scenario, agents)
        assert isinstance(env, envs_jax.DrivingEnv) and env.name == scenario
        assert isinstance(wrapped, envs_jax.AutoResetWrapper)
    assert validate({"scenario": scenario, "algo": algo, "agents": most})["agents"] == most
    with pytest.raises(ValueError, match=f"'agents' for scenario '{scenario}' must be 2..8"):
        validate({"scenario": scenario, "algo": algo, "agents": 9})
