"""The authors' one-shot arrival bonus (merge and intersection): first to arrive gets more; the bookkeeping of the
K-agent versions on the traffic core."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from flax import struct

from envs_jax.traffic_state import TrafficState


def one_shot_arrival(here, arrived, first_arrived, first_reward, second_reward):
    """Bonus for agents reaching their goal for the first time, leader evaluated first.

    ``here[2]``: at the goal now; ``arrived[2]``: arrived at an earlier step (latched);
    ``first_arrived``: 0 nobody yet, 1 leader first, 2 follower first. The leader gets
    ``first_reward`` unless the follower arrived before, then ``second_reward``; the
    follower likewise, seeing the leader's flag of this step (a tie goes to the leader).
    Returns ``(bonus[2], arrived[2], first_arrived)``.
    """
    new_l = here[0] & ~arrived[0]
    bonus_l = jnp.where(new_l, jnp.where(arrived[1], second_reward, first_reward), 0.0)
    first = jnp.where(new_l & ~arrived[1], 1, first_arrived)
    arrived_l = arrived[0] | here[0]
    new_f = here[1] & ~arrived[1]
    bonus_f = jnp.where(new_f, jnp.where(arrived_l, second_reward, first_reward), 0.0)
    first = jnp.where(new_f & ~arrived_l, 2, first)
    return jnp.stack([bonus_l, bonus_f]), jnp.stack([arrived_l, arrived[1] | here[1]]), first.astype(jnp.int32)


def ranked_arrival(here, arrived, first_arrived, first_reward, second_reward):
    """:func:`one_shot_arrival` for K agents: the first agent to arrive gets ``first_reward``, every later one
    ``second_reward``; agents arriving on the same step are ranked in agent order.

    Agent k, arriving now, gets ``first_reward`` when no other agent arrived at an earlier step and no agent
    before it arrives on this one. ``first_arrived``: 0 nobody yet, ``k + 1`` when agent k was first. With two
    agents this is :func:`one_shot_arrival`. Returns ``(bonus[K], arrived[K], first_arrived)``.
    """
    here = jnp.asarray(here, bool)
    arrived = jnp.asarray(arrived, bool)
    new = here & ~arrived
    earlier = jnp.sum(arrived.astype(jnp.int32)) - arrived.astype(jnp.int32) > 0  # another agent, earlier step
    now_before = jnp.cumsum(here.astype(jnp.int32)) - here.astype(jnp.int32) > 0  # an agent before k, this step
    first = new & ~earlier & ~now_before
    bonus = jnp.where(new, jnp.where(first, first_reward, second_reward), 0.0)
    who = jnp.where(jnp.any(first), jnp.argmax(first) + 1, first_arrived)
    return bonus, arrived | here, who.astype(jnp.int32)


@struct.dataclass
class ArrivalState(TrafficState):
    """:class:`TrafficState` plus the arrival bookkeeping of the agents (``merge-k``, ``intersection-k``)."""

    arrived: jax.Array  # [K] latched: reached its goal at some step
    first_arrived: jax.Array  # 0 nobody yet, k + 1 when agent k arrived first


class ArrivalBookkeeping:
    """Mixin for a traffic env whose task's ``outcome`` returns ``info["arrived"]`` and ``info["first_arrived"]``
    (:func:`ranked_arrival`): the state starts with nobody arrived and keeps the flags from step to step."""

    def state_from(self, init: dict, params, key=None):
        _, st = super().state_from(init, params, key)
        fields = {f.name: getattr(st, f.name) for f in dataclasses.fields(st)}
        st = ArrivalState(**fields, arrived=jnp.zeros(self.num_agents, bool), first_arrived=jnp.zeros((), jnp.int32))
        return self.observe(st, params, key), st

    def _step(self, key, state, action, params, record):
        obs, st, reward, cost, done, info, trajectory = super()._step(key, state, action, params, record)
        st = st.replace(arrived=info["arrived"], first_arrived=info["first_arrived"])
        return obs, st, reward, cost, done, info, trajectory
