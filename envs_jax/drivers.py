"""``road.act()`` for V vehicle slots: controlled MDP vehicles and IDM/MOBIL drivers, in list order.

In highway-env every vehicle acts in ``road.vehicles`` order within a frame:

* a controlled MDP vehicle (``ControlledVehicle.act(None)``): ``follow_road``, then
  steering towards its target lane and the proportional speed controller;
* an IDM vehicle (``IDMVehicle.act``), unless crashed: ``follow_road``,
  ``change_lane_policy`` (MOBIL, gated by the lane-change timer, or the abort rule
  during a lane change), steering towards the target lane, and IDM acceleration
  against the front vehicle of the current lane (during a lane change, the minimum
  with the front vehicle of the target lane), clipped to ``acc_max``;
* a plain vehicle (continuous actions) keeps its stored action.

Only the abort rule reads another vehicle's mutable state (its target lane), so only
it depends on the order: a vehicle sees the *final* target of the vehicles before it
in the list and the frame's *initial* target of those after it. Everything else is
computed for all slots at once; the abort rule is solved as the fixed point of
"each vehicle's decision given the others' decisions" (a ``while_loop``, typically
one or two rounds), which is unique and equal to the sequential result because a
vehicle depends only on the vehicles before it.

Only the drivers whose timer fired or who are changing lanes need their side and
target lanes on a frame (a few of many): every vehicle's own lane is searched for all,
the rest for those drivers only, a group at a time
(:func:`~envs_jax.sparse.grouped_rows`), or on small roads packed across the batch
(:func:`~envs_jax.sparse.batch_rows`; docs/performance.md).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from envs_jax import idm, trig
from envs_jax import lane_locate as LL
from envs_jax import lanes as L
from envs_jax import neighbours as N
from envs_jax import vehicle as Veh
from envs_jax.materialize import materialize
from envs_jax.mobil import ObjectTable, accept, free_acceleration, pair_acceleration
from envs_jax.road import Road
from envs_jax.sparse import batch_rows, grouped_rows, sparse_map
from envs_jax.traffic_state import TrafficState


def follow_road(road: Road, st: TrafficState, acting, circles=None):
    """``ControlledVehicle.follow_road`` for the ``acting`` slots: past ``length - 2.5`` m of the
    target lane, switch to ``road.next_lane``. Returns ``(target_lane, route_ptr)``. ``circles``: the slots'
    :func:`~envs_jax.lane_locate.circle_coords` if already known."""
    tl, rp = st.target_lane, st.route_ptr
    if circles is None:
        circles = LL.circle_coords(road.lanes, st.x, st.y)
    s, _ = LL.lane_coords(road.lanes, st.x, st.y, circles, tl, sine=False)  # the longitudinal coordinate only
    end = acting & (s > road.lanes.col("length")[tl] - L.VEHICLE_LENGTH / 2)
    nl, nrp = sparse_map(road.next_lane, end, tl, s, st.route_roads, st.route_ids, st.route_len, rp,
                         fraction=1 / 32)
    return jnp.where(end, nl, tl), jnp.where(end, nrp, rp)


def side_lanes(road: Road, lane):
    """``network.side_lanes(lane)``: the lanes left (id - 1) and right (id + 1) on the same road,
    with flags for their existence (the lane itself stands in for a missing one)."""
    road_lanes = jnp.asarray(road.road_lanes)
    r = jnp.asarray(road.lane_road)[lane]
    i = jnp.asarray(road.lane_id)[lane]
    n = jnp.asarray(road.road_num_lanes)[r]
    has_left, has_right = i > 0, i < n - 1
    left = jnp.where(has_left, road_lanes[r, jnp.maximum(i - 1, 0)], lane)
    right = jnp.where(has_right, road_lanes[r, jnp.minimum(i + 1, road_lanes.shape[1] - 1)], lane)
    return left, right, has_left, has_right


def objects(st: TrafficState, obstacles):
    """Positions, headings, speeds and presence of every road object: slots, then obstacles."""
    if obstacles is None:
        return st.x, st.y, st.heading, st.speed, st.alive
    ox, oy, oh = obstacles[:, 0], obstacles[:, 1], obstacles[:, 2]
    cat = lambda a, b: jnp.concatenate([a, b.astype(a.dtype)])
    return (cat(st.x, ox), cat(st.y, oy), cat(st.heading, oh), cat(st.speed, jnp.zeros_like(ox)),
            jnp.concatenate([st.alive, jnp.ones(ox.shape, bool)]))


def decision_rows(n_slots: int) -> int:
    """Drivers whose lane-change work runs at once on a frame (:func:`~envs_jax.sparse.grouped_rows`): a timer
    fires about once a second per driver, so on a road of many slots a quarter of them at once covers a frame's
    deciding drivers. On a small road (1) rarely more than one decides on a frame, and under ``vmap`` the deciding
    drivers of the whole batch are packed together instead (:func:`~envs_jax.sparse.batch_rows`), so the
    environment with the most deciding drivers does not set the work of all."""
    return 1 if n_slots <= 12 else -(-n_slots // 4)


def road_act(road: Road, st: TrafficState, is_idm, is_mdp, p: idm.IDMParams, obstacles=None,
             circles=None) -> TrafficState:
    """One frame of ``road.act()``: new target lanes, route pointers, timers and stored actions.

    ``is_idm``, ``is_mdp``: ``[V]`` flags of the slots' vehicle classes (neither: a
    plain ``Vehicle``); ``obstacles``: ``[O, >= 3]`` rows ``x, y, heading, ...`` or None;
    ``circles``: the slots' :func:`~envs_jax.lane_locate.circle_coords` if already known.
    """
    lanes = road.lanes
    n_slots = st.x.shape[0]
    is_idm = jnp.asarray(is_idm, bool)
    is_mdp = jnp.asarray(is_mdp, bool)
    controlled_class = is_idm | is_mdp  # ``isinstance(v, ControlledVehicle)``
    acting_idm = st.alive & is_idm & ~st.crashed
    follows = st.alive & (is_mdp | acting_idm)
    slot = jnp.arange(n_slots)

    computed = circles is None  # else: carried in from the last frame, already a buffer
    if circles is None:
        circles = LL.circle_coords(lanes, st.x, st.y)
    if computed and circles[0].size:  # [V, C]: read by follow_road and every lane below, computed once
        circles = materialize(circles)
    t0 = st.target_lane
    t1, route_ptr = follow_road(road, st, follows, circles)

    px, py, ph, pv, valid = objects(st, obstacles)
    n_obj = px.shape[0]
    is_vehicle = jnp.arange(n_obj) < n_slots
    if n_obj > n_slots:  # the obstacles' too
        extra = LL.circle_coords(lanes, px[n_slots:], py[n_slots:])
        circles = tuple(jnp.concatenate([c, e.astype(c.dtype)]) for c, e in zip(circles, extra))
        if circles[0].size:  # [N, C]: read by every lane below, computed once
            circles = materialize(circles)
    left, right, has_left, has_right = side_lanes(road, st.lane)

    # a few drivers decide on a frame (their timer fired, or they are changing lanes): every vehicle's own lane
    # here, and the side and target lanes only for them (``deciding`` below)
    s_own, lat_own = materialize(N.coordinates_on(lanes, st.lane, px, py, circles))  # [V, N]
    eligible = N.on_lane(lanes, st.lane, s_own, lat_own) & valid & (jnp.arange(n_obj) != slot[:, None])
    front_own = materialize(N.front_rear(s_own[slot, slot], s_own, eligible)[0])

    pad = lambda a, v: jnp.concatenate([a, jnp.full((n_obj - n_slots,), v, a.dtype)])
    # per object, read by every pair below (XLA would otherwise recompute the trigonometry per pair)
    sin_h, cos_h = materialize(trig.sin_cos(ph))
    objs = ObjectTable(speed=pv, cos_h=cos_h, sin_h=sin_h,
                       target_speed=pad(jnp.where(controlled_class, st.target_speed, 0.0), 0.0),
                       speed_limit=pad(lanes.col("speed_limit")[st.lane], 0.0),
                       is_vehicle=is_vehicle, s_own=s_own)
    free_me = materialize(free_acceleration(objs, slot, st.delta, p))  # a power, read by several pairs
    a_lane = pair_acceleration(objs, slot, front_own, st.delta, p, free=free_me)  # me behind my lane's front

    # MOBIL, at the timer's pace, when no lane change is ongoing
    changing = st.lane != t1
    gate = acting_idm & ~changing & (p.lane_change_delay < st.timer)
    timer = jnp.where(gate, 0.0, st.timer)
    has_route = route_ptr < st.route_len
    head = jnp.clip(route_ptr, 0, st.route_ids.shape[-1] - 1)
    route_id = jnp.take_along_axis(st.route_ids, head[:, None], axis=-1)[:, 0]
    fixes_lane = has_route & (route_id >= 0)
    lane_id = jnp.asarray(road.lane_id)[st.lane]
    moving = jnp.abs(st.speed) >= 1
    lane_road = jnp.asarray(road.lane_road)
    abortable = acting_idm & changing & (lane_road[st.lane] == lane_road[t1])

    def search(me, e):
        """Every object on the own, left, right and target lanes of the drivers ``me`` (``[G]`` slots): the
        query lanes ``[G, 4]``, the coordinates ``[G, 4, N]`` and the front and rear objects ``[G, 4]``."""
        take = lambda a: a[me]
        query = jnp.stack([take(e["lane"]), take(e["left"]), take(e["right"]), take(e["t1"])], axis=-1)
        # materialised once: otherwise XLA recomputes the coordinates inside each consumer
        s, lat = materialize(N.coordinates_on(lanes, query, e["px"], e["py"], e["circles"]))
        not_me = jnp.arange(n_obj) != me[:, None]
        on = N.on_lane(lanes, query, s, lat) & e["valid"] & not_me[:, None, :]
        g = jnp.arange(me.shape[0])
        front, rear = materialize(N.front_rear(s[g, :, me], s, on))  # computed once, not per consumer
        return query, s, lat, front, rear

    def deciding(me, e):
        """The lane-change work of the drivers ``me`` (``[G]`` slots) of the environment ``e`` (its arrays, named
        below): MOBIL's choice where the timer fired, the rivals of the abort rule and the IDM acceleration behind
        the front vehicle of the chosen lane."""
        take = lambda a: a[me]
        objs, p = e["objs"], e["p"]
        query, s, lat, front, rear = search(me, e)
        g = jnp.arange(me.shape[0])
        s_self, lat_self = s[g, :, me], lat[g, :, me]  # [G, 4]: the vehicle's own coordinates on its query lanes

        def reachable(q):
            lane_q = query[:, q]
            return ((jnp.abs(lat_self[:, q]) <= 2 * lanes.col("width")[lane_q]) & (0 <= s_self[:, q])
                    & (s_self[:, q] < lanes.col("length")[lane_q] + L.VEHICLE_LENGTH)
                    & ~jnp.asarray(lanes.forbidden)[lane_q])

        # every acceleration MOBIL compares, for both side lanes, in one batch: (ego, front) pairs
        lf, lr, rf, rr = front[:, 1], rear[:, 1], front[:, 2], rear[:, 2]
        op, of = front[:, 0], rear[:, 0]
        ego = jnp.stack([lr, lr, me, rr, rr, me, of, of], axis=-1)
        fro = jnp.stack([lf, me, lf, rf, me, rf, me, op], axis=-1)
        delta = take(e["delta"])[:, None]
        # the free-road term (a power) depends on the ego and the deciding vehicle only: four egos per row
        free4 = materialize(free_acceleration(objs, jnp.stack([lr, rr, of], axis=-1), delta, p))
        f_lr, f_rr, f_of, f_me = free4[:, 0], free4[:, 1], free4[:, 2], take(e["free_me"])
        free = jnp.stack([f_lr, f_lr, f_me, f_rr, f_rr, f_me, f_of, f_of], axis=-1)
        acc = pair_acceleration(objs, ego, fro, delta, p, free=free)
        # me behind the old preceding, the old follower behind me / behind the old preceding
        common = (take(e["a_lane"]), acc[:, 6], acc[:, 7])
        target = take(e["t1"])
        for q, exists, step, k in ((1, "has_left", -1, 0), (2, "has_right", 1, 3)):
            target_id = jnp.asarray(road.lane_id)[target]
            ok = accept(acc[:, k], acc[:, k + 1], acc[:, k + 2], *common, take(e["lane_id"]) + step, target_id,
                        take(e["fixes_lane"]), take(e["route_id"]), p)
            target = jnp.where(take(e["gate"]) & take(e[exists]) & reachable(q) & take(e["moving"]) & ok,
                               query[:, q], target)

        # abort rule: another (controlled-class) vehicle is changing into the same lane, within the desired gap
        speed, cos_v, sin_v = objs.speed[:n_slots], objs.cos_h[:n_slots], objs.sin_h[:n_slots]
        d = take(objs.s_own)[:, :n_slots] - s_self[:, :1]  # [G, V]: lane_distance_to(v), on the vehicle's own lane
        dv = idm.velocity_gap(take(speed)[:, None], take(cos_v)[:, None], take(sin_v)[:, None],
                              speed[None, :], cos_v[None, :], sin_v[None, :])
        d_star = idm.desired_gap(take(speed)[:, None], dv, p)
        rivals = (e["alive"][None, :] & e["controlled"][None, :] & (jnp.arange(n_slots) != me[:, None])
                  & (e["lane"][None, :] != take(e["t1"])[:, None]) & (0 < d) & (d < d_star))
        q_target = jnp.argmax(query == target[:, None], axis=-1)
        front_target = jnp.take_along_axis(front, q_target[:, None], axis=-1)[:, 0]
        a_target = pair_acceleration(objs, me, front_target, take(e["delta"]), p, free=take(e["free_me"]))
        return target, rivals, a_target

    env = dict(lane=st.lane, left=left, right=right, has_left=has_left, has_right=has_right, t1=t1, px=px, py=py,
               circles=circles, valid=valid, objs=objs, p=p, delta=st.delta, free_me=free_me, a_lane=a_lane,
               lane_id=lane_id, fixes_lane=fixes_lane, route_id=route_id, gate=gate, moving=moving,
               alive=st.alive, controlled=controlled_class)
    needs = gate | (acting_idm & changing)
    if decision_rows(n_slots) == 1:  # a small road: the batch's few deciding drivers packed together
        target, rivals, a_target = batch_rows(lambda me, e: [o[0] for o in deciding(me[None], e)], needs, env)
    else:
        target, rivals, a_target = grouped_rows(lambda me: deciding(me, env), needs, decision_rows(n_slots))
    target = jnp.where(gate, target, t1)
    before = slot[None, :] < slot[:, None]
    base = jnp.where(acting_idm, target, jnp.where(follows, t1, t0))

    def decide(final):
        seen = jnp.where(before, final[None, :], t0[None, :])
        abort = abortable & jnp.any(rivals & (seen == t1[:, None]), axis=1)
        return jnp.where(abort, st.lane, base)

    def body(carry):
        final, _ = carry
        new = decide(final)
        return new, jnp.any(new != final)

    first = decide(base)
    final, _ = jax.lax.while_loop(lambda c: c[1], body, (first, jnp.any(first != base)))

    # low-level commands
    s_final, lat_final = LL.lane_coords(lanes, st.x, st.y, (circles[0][:n_slots], circles[1][:n_slots]), final)
    steering = Veh.steering_control(lanes, final, s_final, lat_final, st.heading, st.speed)
    a_idm = jnp.where(st.lane != final, jnp.minimum(a_lane, a_target), a_lane)
    a_idm = jnp.clip(a_idm, -p.acc_max, p.acc_max)
    a_mdp = Veh.speed_control(st.target_speed, st.speed)
    commands = follows
    acceleration = jnp.where(acting_idm, a_idm, a_mdp)
    return st.replace(target_lane=final.astype(jnp.int32), route_ptr=route_ptr, timer=timer,
                      steering=jnp.where(commands, steering, st.steering).astype(st.x.dtype),
                      acceleration=jnp.where(commands, acceleration, st.acceleration).astype(st.x.dtype))
