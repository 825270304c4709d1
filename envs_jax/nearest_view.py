"""The authors' kinematic observation for K agents among V vehicles (docs/scenarios.md).

The two-agent view (:func:`envs_jax.observation.observe`) is highway-env's
``KinematicObservation`` with features ``[x, y, vx, vy]``, absolute coordinates, no
normalisation and ``vehicles_count = 2``: an agent's own row, then the nearest other
vehicle closer than ``PERCEPTION_DISTANCE`` (strictly), zeros when there is none.
Here ``vehicles_count = count`` rows: the agent's own, then the ``count - 1`` nearest
other present vehicles (Euclidean distance, nearest first; ties go to the vehicle
listed first in ``order``), each zero when it is not closer than the perception
distance. With two vehicles and ``count = 2`` this is the two-agent view.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from envs_jax.observation import PERCEPTION_DISTANCE, kinematics


def observe(x, y, heading, speed, alive, order, num_observers: int, count: int,
            perception_distance=PERCEPTION_DISTANCE):
    """Observations ``[num_observers, 4 * count]`` (one row per agent, flattened).

    ``x, y, heading, speed, alive``: per-slot ``[V]`` arrays. ``order``: a static
    permutation of the V slots listing the observers first (agent order), then the
    other slots; it decides ties. ``count`` is at most V.
    """
    order = np.asarray(order)
    n = order.shape[0]
    if not 1 <= count <= n:
        raise ValueError(f"count must be in 1..{n} (the vehicles in the view), got {count}")
    x, y, heading, speed, alive = (jnp.asarray(a)[order] for a in (x, y, heading, speed, alive))
    feats = kinematics(x, y, heading, speed)  # [V, 4]
    k = num_observers
    dx = x[None, :] - x[:k, None]
    dy = y[None, :] - y[:k, None]
    dist = jnp.sqrt(dx * dx + dy * dy)
    own = np.arange(n)[None, :] == np.arange(k)[:, None]
    dist = jnp.where(own | ~alive[None, :], jnp.inf, dist)  # [K, V]
    nearest = jnp.argsort(dist, axis=1, stable=True)[:, :count - 1]
    visible = jnp.take_along_axis(dist, nearest, axis=1) < perception_distance
    others = jnp.where(visible[..., None], feats[nearest], 0.0)  # [K, count - 1, 4]
    return jnp.concatenate([feats[:k], others.reshape(k, 4 * (count - 1))], axis=-1)


class NearestViewEnv:
    """Mixin for a traffic env whose agents observe this view: the task names ``view_order`` (the slots, agents
    first) and ``vehicles_count`` (rows per agent). Call :meth:`use_nearest_view` after the env's ``__init__``."""

    def use_nearest_view(self) -> None:
        self.obs_config = None
        self.obs_shape = (self.num_agents, 4 * self.task.vehicles_count)

    def observe(self, state, params, key=None):
        return observe(state.x, state.y, state.heading, state.speed, state.alive, self.task.view_order,
                       self.num_agents, self.task.vehicles_count)
