"""State of a simulation with V vehicle slots (controlled agents and background traffic).

Slots are in highway-env's ``road.vehicles`` order, which is the order in which
vehicles act, step and are checked for collisions; the controlled agents are the
slots named by the environment's static ``controlled`` index list, the others
are IDM/MOBIL drivers. A slot whose ``alive`` flag is false holds no vehicle: it
is skipped by the neighbour search, the collision checks and the observations,
and its arrays stay as they are.
"""

from __future__ import annotations

import jax
from flax import struct


@struct.dataclass
class TrafficState:
    """Per-slot arrays have shape ``[V]`` (``impact`` ``[V, 2]``, routes ``[V, R]``)."""

    x: jax.Array
    y: jax.Array
    heading: jax.Array
    speed: jax.Array
    alive: jax.Array  # the slot holds a vehicle
    crashed: jax.Array  # latched once a collision happened
    on_road: jax.Array  # on its closest lane (``vehicle.on_road``)
    lane: jax.Array  # closest lane, global index (``vehicle.lane_index``)
    target_lane: jax.Array  # lane followed by the steering controller
    target_speed: jax.Array
    speed_index: jax.Array  # controlled MDP vehicles: index into the target-speed grid
    steering: jax.Array  # stored low-level action
    acceleration: jax.Array
    impact: jax.Array  # translation applied on the next frame
    has_impact: jax.Array
    timer: jax.Array  # IDM lane-change timer [s]
    delta: jax.Array  # IDM exponent of each driver (``randomize_behavior``)
    route_roads: jax.Array  # planned route (road indices), -1 padded
    route_ids: jax.Array  # lane id per route step, -1 = any
    route_len: jax.Array
    route_ptr: jax.Array
    time: jax.Array  # policy steps taken
