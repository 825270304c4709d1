"""Road network: lane connectivity, closest lane, next lane and routes.

A :class:`RoadNetwork` is built on the host exactly like highway-env's (a dict
of dicts of lane lists, insertion-ordered), then frozen into padded integer
tables so that every query is a fixed-shape JAX function:

* lanes are numbered in the order highway-env's ``get_closest_lane_index``
  scans them (``for _from in graph: for _to in graph[_from]: for _id ...``), so
  ``argmin`` reproduces its tie-breaking;
* roads are ``(from, to)`` pairs in the same order; ``road_lanes[road, id]`` is
  the global lane number and ``road_next[road, k]`` the k-th successor road, in
  ``graph[to]`` insertion order.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax import lane_locate as LL
from envs_jax import lanes as L


class RoadNetwork:
    """Host-side builder mirroring ``highway_env.road.road.RoadNetwork``."""

    def __init__(self):
        self.graph: dict[str, dict[str, list[L.LaneSpec]]] = {}

    def add_lane(self, _from: str, _to: str, lane: L.LaneSpec) -> None:
        self.graph.setdefault(_from, {}).setdefault(_to, []).append(lane)

    def freeze(self) -> "Road":
        return Road(self)


class Road:
    """Frozen road network: a lane table plus padded connectivity tables (all static)."""

    def __init__(self, network: RoadNetwork):
        specs, lane_road, lane_id, names = [], [], [], []
        roads: list[tuple[str, str]] = []
        for _from, to_dict in network.graph.items():
            for _to, lanes in to_dict.items():
                roads.append((_from, _to))
                for i, spec in enumerate(lanes):
                    specs.append(spec)
                    lane_road.append(len(roads) - 1)
                    lane_id.append(i)
                    names.append((_from, _to, i))
        self.lanes = L.LaneTable(specs)
        self.lane_names = names
        self.roads = roads
        self.road_index = {r: i for i, r in enumerate(roads)}
        self.lane_index = {n: i for i, n in enumerate(names)}
        n_roads = len(roads)
        max_lanes = max(len(network.graph[f][t]) for f, t in roads)
        self.road_lanes = -np.ones((n_roads, max_lanes), dtype=np.int32)
        self.road_num_lanes = np.zeros(n_roads, dtype=np.int32)
        for g, (f, t, i) in enumerate(names):
            self.road_lanes[self.road_index[(f, t)], i] = g
        for r, (f, t) in enumerate(roads):
            self.road_num_lanes[r] = len(network.graph[f][t])
        succ = [[self.road_index[(t, nt)] for nt in network.graph.get(t, {})] for f, t in roads]
        self.max_next = max(1, max(len(s) for s in succ))
        self.road_next = -np.ones((n_roads, self.max_next), dtype=np.int32)
        for r, s in enumerate(succ):
            self.road_next[r, : len(s)] = s
        self.lane_road = np.array(lane_road, dtype=np.int32)
        self.lane_id = np.array(lane_id, dtype=np.int32)
        self.road_from = np.array([f for f, _ in roads])
        self.road_to = np.array([t for _, t in roads])
        node_names = sorted(set(self.road_from) | set(self.road_to))
        node_id = {n: i for i, n in enumerate(node_names)}
        self.road_from_id = np.array([node_id[f] for f, _ in roads], dtype=np.int32)
        self.road_to_id = np.array([node_id[t] for _, t in roads], dtype=np.int32)

    # -- host helpers -------------------------------------------------------------------------
    def lane(self, _from: str, _to: str, _id: int = 0) -> int:
        """Global lane number of ``(_from, _to, _id)``; raises ``ValueError`` if unknown."""
        try:
            return self.lane_index[(_from, _to, _id)]
        except KeyError:
            raise ValueError(f"unknown lane {(_from, _to, _id)!r}; lanes are {self.lane_names}") from None

    def route(self, nodes: list[str], first_lane_id: int | None = None, length: int | None = None):
        """Encode a route through ``nodes`` as padded (road, lane id) arrays.

        Mirrors ``ControlledVehicle.plan_route_to``: the first entry carries the
        vehicle's lane id, the others ``None`` (encoded -1). Returns
        ``(roads[R], ids[R], n)`` padded with -1 to ``length``.
        """
        roads, ids = [], []
        for k, (f, t) in enumerate(zip(nodes[:-1], nodes[1:])):
            if (f, t) not in self.road_index:
                raise ValueError(f"route step {f}->{t} is not a road of this network")
            roads.append(self.road_index[(f, t)])
            ids.append(first_lane_id if (k == 0 and first_lane_id is not None) else -1)
        length = length or len(roads)
        pad = length - len(roads)
        return (np.array(roads + [-1] * pad, dtype=np.int32),
                np.array(ids + [-1] * pad, dtype=np.int32), len(roads))

    # -- traced queries -----------------------------------------------------------------------
    def closest_lane(self, px, py, heading):
        """``get_closest_lane_index(position, heading)``: argmin of distance-with-heading (first wins)."""
        return LL.locate(self.lanes, px, py, heading)[0].astype(jnp.int32)

    def next_lane(self, lane, s, route_roads, route_ids, route_len, route_ptr):
        """``RoadNetwork.next_lane``: the lane to follow once ``lane`` is finished.

        ``s`` is the vehicle's longitudinal coordinate on ``lane``. With a route
        whose next step starts where the current road ends, follow it; otherwise
        pick, among the successor roads, the one whose candidate lane is closest
        to the projection of the position on the current lane's centre line. The
        candidate keeps the lane id when both roads have as many lanes, else it
        is the closest lane of the next road. Returns ``(lane, route_ptr)``.
        """
        road_lanes = jnp.asarray(self.road_lanes)
        road_num = jnp.asarray(self.road_num_lanes)
        road_next = jnp.asarray(self.road_next)
        lane_road = jnp.asarray(self.lane_road)[lane]
        lane_id = jnp.asarray(self.lane_id)[lane]
        from_id = jnp.asarray(self.road_from_id)
        to_id = jnp.asarray(self.road_to_id)

        # Route bookkeeping: drop the first step if it is the current road.
        has_route = route_ptr < route_len
        head = jnp.clip(route_ptr, 0, route_roads.shape[-1] - 1)
        pop = has_route & (route_roads[head] == lane_road)
        route_ptr = route_ptr + pop.astype(route_ptr.dtype)
        has_route = route_ptr < route_len
        head = jnp.clip(route_ptr, 0, route_roads.shape[-1] - 1)
        route_road = route_roads[head]
        follow = has_route & (from_id[jnp.maximum(route_road, 0)] == to_id[lane_road])
        route_lane_id = route_ids[head]

        # The projection of the position on the current centre line.
        qx, qy = L.position(self.lanes, lane, s, jnp.zeros_like(s))
        circles = LL.circle_coords(self.lanes, qx, qy)

        # Candidates: every successor road (padded), each with its chosen lane and distance.
        succ = road_next[lane_road]  # [S]
        slot = jnp.arange(succ.shape[-1])
        cand_roads = jnp.where(follow, jnp.where(slot == 0, route_road, -1), succ)
        valid = cand_roads >= 0
        cand_roads = jnp.maximum(cand_roads, 0)
        n_next = road_num[cand_roads]  # [S]
        same_count = n_next == road_num[lane_road]
        lanes_of = road_lanes[cand_roads]  # [S, M]
        lane_exists = jnp.arange(road_lanes.shape[-1])[None, :] < n_next[:, None]
        # distance of the projection to each candidate lane (only those: S x M lanes, not all)
        cand = jnp.maximum(lanes_of, 0)
        q_s, q_lat = LL.lane_coords(self.lanes, qx, qy, jax.tree_util.tree_map(lambda a: a[None, None], circles), cand)
        dist = L.distance_from_coords(self.lanes.col("length")[cand], q_s, q_lat)  # [S, M]
        d_all = jnp.where(lane_exists, dist, jnp.inf)
        closest_id = jnp.argmin(d_all, axis=-1)
        keep_id = jnp.where(follow & (route_lane_id >= 0), route_lane_id, lane_id)
        keep_id = jnp.minimum(keep_id, n_next - 1)
        chosen_id = jnp.where(same_count, keep_id, closest_id)
        chosen_lane = jnp.take_along_axis(lanes_of, chosen_id[:, None], axis=-1)[:, 0]
        chosen_d = jnp.take_along_axis(d_all, chosen_id[:, None], axis=-1)[:, 0]
        chosen_d = jnp.where(valid, chosen_d, jnp.inf)
        best = jnp.argmin(chosen_d)
        new_lane = jnp.where(jnp.any(valid), chosen_lane[best], lane)
        return new_lane.astype(jnp.int32), route_ptr
