"""Pictures of the road and the cars with Pillow, from the JAX lane table.

Drawing follows highway-env's ``road/graphics.py``: the world is seen from above with x to the right and y
*down* (pygame's convention, so the pictures look like highway-env's), and every lane side is drawn by its line
type: STRIPED as 3 m stripes every 4.33 m starting at s = 0, CONTINUOUS as back-to-back 4.33 m segments,
CONTINUOUS_LINE as one straight segment from the lane's start to its end (as highway-env does, even on the merge
ramp's sine lane), NONE not at all; white, ``max(int(0.3 m * scale), 1)`` pixels wide. Lane surfaces are grey on
a green background (highway-env paints everything grey) so that leaving the road is visible. Cars are 5 x 2 m
rectangles: the leader green, the follower blue (highway-env's ego and "other" colours), red once crashed, with
a dark bar across the front.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np

__all__ = ["COLORS", "ROLES", "WHOLE_ROAD_EXTENT", "View", "draw_frame", "draw_road", "draw_vehicle", "fit_view",
           "lane_surfaces", "marking_segments", "road_bounds", "vehicle_corners", "vehicle_roles"]

VEHICLE_LENGTH, VEHICLE_WIDTH = 5.0, 2.0
FRONT_BAR = 0.6  # metres of the car's front drawn dark
STRIPE_SPACING, STRIPE_LENGTH, STRIPE_WIDTH = 4.33, 3.0, 0.3  # highway-env LaneGraphics

COLORS = {
    "background": (96, 140, 84),  # off-road
    "road": (100, 100, 100),  # highway-env's GREY
    "marking": (255, 255, 255),
    "leader": (50, 200, 0),  # highway-env EGO_COLOR (GREEN)
    "follower": (100, 200, 255),  # highway-env BLUE
    "traffic": (200, 170, 230),  # background (IDM/MOBIL) vehicles: a pale purple, apart from the agents
    "crashed": (255, 100, 100),  # highway-env RED
    "outline": (60, 60, 60),  # highway-env BLACK
    "obstacle": (200, 200, 0),  # highway-env YELLOW
    "text": (255, 255, 255),
}


# ---------------------------------------------------------------------------------------------------------
# World -> pixels


@dataclasses.dataclass(frozen=True)
class View:
    """``pixel = (world - origin) * scale``; x right, y down. ``width x height`` pixels."""

    origin_x: float
    origin_y: float
    scale: float  # pixels per metre
    width: int
    height: int

    def to_pixels(self, x, y):
        return (np.asarray(x, np.float64) - self.origin_x) * self.scale, \
            (np.asarray(y, np.float64) - self.origin_y) * self.scale


def fit_view(xs, ys, margin: float = 12.0, min_extent: float = 60.0, max_width: int = 960, max_height: int = 720,
             max_scale: float = 8.0) -> View:
    """The smallest view around the points ``xs, ys`` (plus ``margin`` metres, at least ``min_extent`` metres
    each way) that fits ``max_width x max_height`` pixels at no more than ``max_scale`` px/m (even sizes, for
    video encoders)."""
    xs, ys = np.asarray(xs, np.float64).ravel(), np.asarray(ys, np.float64).ravel()
    finite = np.isfinite(xs) & np.isfinite(ys)
    if not finite.any():
        raise ValueError("fit_view needs at least one finite point")
    x0, x1 = xs[finite].min() - margin, xs[finite].max() + margin
    y0, y1 = ys[finite].min() - margin, ys[finite].max() + margin
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    w, h = max(x1 - x0, min_extent), max(y1 - y0, min_extent)
    scale = min(max_width / w, max_height / h, max_scale)
    width = 2 * int(math.ceil(w * scale / 2))
    height = 2 * int(math.ceil(h * scale / 2))
    return View(cx - width / (2 * scale), cy - height / (2 * scale), scale, width, height)


# ---------------------------------------------------------------------------------------------------------
# Road


_POSITION_FNS: dict[int, tuple] = {}  # id(lane table) -> (table, jitted position), kept for the process


def _lane_points(lanes, idx: np.ndarray, s: np.ndarray, lat: np.ndarray):
    """World positions of (s, lat) on lanes ``idx`` (broadcast), evaluated by the simulator's own
    ``envs_jax.lanes.position``, jitted once per lane table on inputs padded to a power of two (at least 256):
    op-by-op evaluation would compile a small program per operation and per lane length."""
    from envs_jax import lanes as L

    idx, s, lat = np.broadcast_arrays(np.asarray(idx, np.int32), np.asarray(s, np.float64),
                                      np.asarray(lat, np.float64))
    shape, n = idx.shape, idx.size
    entry = _POSITION_FNS.get(id(lanes))
    if entry is None or entry[0] is not lanes:
        entry = (lanes, jax.jit(lambda i, ss, ll: L.position(lanes, i, ss, ll)))
        _POSITION_FNS[id(lanes)] = entry
    size = max(256, 1 << max(0, n - 1).bit_length())
    pad = lambda a: np.concatenate([a.ravel(), np.zeros(size - n, a.dtype)])
    x, y = entry[1](pad(idx), pad(s), pad(lat))
    return (np.asarray(x, np.float64)[:n].reshape(shape), np.asarray(y, np.float64)[:n].reshape(shape))


def marking_segments(lanes) -> list[tuple[float, float, float, float]]:
    """Every lane-marking segment ``(x0, y0, x1, y1)`` in world coordinates, by line type (see module doc)."""
    from envs_jax import lanes as L

    rows, s0s, s1s, lats = [], [], [], []
    length = lanes.np_col("length")
    width = lanes.np_col("width")
    for i in range(lanes.size):
        n = int(math.ceil(length[i] / STRIPE_SPACING)) + 1
        k = np.arange(n) * STRIPE_SPACING
        for side in range(2):
            kind = int(lanes.line_types[i, side])
            if kind == L.LINE_STRIPED:
                starts, ends = k, k + STRIPE_LENGTH
            elif kind == L.LINE_CONTINUOUS:
                starts, ends = k, k + STRIPE_SPACING
            elif kind == L.LINE_CONTINUOUS_LINE:
                starts, ends = np.array([0.0]), np.array([length[i]])
            else:
                continue
            starts, ends = np.clip(starts, 0, length[i]), np.clip(ends, 0, length[i])
            keep = np.abs(ends - starts) > 0.5 * STRIPE_LENGTH  # highway-env's draw_stripes filter
            rows += [i] * int(keep.sum())
            s0s += starts[keep].tolist()
            s1s += ends[keep].tolist()
            lats += [(side - 0.5) * width[i]] * int(keep.sum())
    if not rows:
        return []
    k = len(rows)
    x, y = _lane_points(lanes, np.array(rows + rows), np.array(s0s + s1s), np.array(lats + lats))
    return list(zip(x[:k], y[:k], x[k:], y[k:]))


def lane_surfaces(lanes, step: float = 1.0) -> list[np.ndarray]:
    """One world-coordinate polygon ``[K, 2]`` per lane: its left edge forward, then its right edge back."""
    length = lanes.np_col("length")
    width = lanes.np_col("width")
    ss = [np.linspace(0.0, length[i], max(2, int(math.ceil(length[i] / step)) + 1)) for i in range(lanes.size)]
    rows = np.concatenate([np.full(len(s), i) for i, s in enumerate(ss)])
    s_all = np.concatenate(ss)
    half = width[rows] / 2
    x, y = _lane_points(lanes, np.concatenate([rows, rows]), np.concatenate([s_all, s_all]),
                        np.concatenate([-half, half]))  # every lane's left edge, then every right edge
    m = len(s_all)
    out, start = [], 0
    for s in ss:
        sl = slice(start, start + len(s))
        sr = slice(m + start, m + start + len(s))
        out.append(np.concatenate([np.stack([x[sl], y[sl]], 1), np.stack([x[sr], y[sr]], 1)[::-1]]))
        start += len(s)
    return out


WHOLE_ROAD_EXTENT = 250.0  # metres: roads at most this large are shown whole (racetrack, intersection)


def road_bounds(road) -> tuple[tuple[float, float], tuple[float, float]]:
    """``((xmin, xmax), (ymin, ymax))`` of all lane surfaces."""
    pts = np.concatenate(lane_surfaces(road.lanes, step=5.0))
    return (float(pts[:, 0].min()), float(pts[:, 0].max())), (float(pts[:, 1].min()), float(pts[:, 1].max()))


def draw_road(road, view: View, obstacles=None):
    """A Pillow image of the road (surfaces, markings) and static obstacles in ``view``."""
    from PIL import Image, ImageDraw

    img = Image.new("RGB", (view.width, view.height), COLORS["background"])
    draw = ImageDraw.Draw(img)
    for poly in lane_surfaces(road.lanes):
        px, py = view.to_pixels(poly[:, 0], poly[:, 1])
        draw.polygon(list(zip(px.tolist(), py.tolist())), fill=COLORS["road"])
    line_w = max(int(STRIPE_WIDTH * view.scale), 1)
    for x0, y0, x1, y1 in marking_segments(road.lanes):
        (px0, px1), (py0, py1) = view.to_pixels([x0, x1], [y0, y1])
        draw.line([(px0, py0), (px1, py1)], fill=COLORS["marking"], width=line_w)
    if obstacles is not None:
        for x, y, h, length, width in np.asarray(obstacles, np.float64).reshape(-1, 5):
            _draw_box(draw, view, x, y, h, length, width, COLORS["obstacle"], front=False)
    return img


def vehicle_corners(x: float, y: float, heading: float, length: float = VEHICLE_LENGTH,
                    width: float = VEHICLE_WIDTH) -> np.ndarray:
    """World corners ``[4, 2]`` of a ``length x width`` box centred at (x, y): rear-left, front-left,
    front-right, rear-right (left = +90 degrees from the heading)."""
    u = np.array([math.cos(heading), math.sin(heading)])
    v = np.array([-u[1], u[0]])
    c = np.array([x, y], np.float64)
    hl, hw = length / 2, width / 2
    return np.stack([c - hl * u + hw * v, c + hl * u + hw * v, c + hl * u - hw * v, c - hl * u - hw * v])


def _draw_box(draw, view: View, x, y, heading, length, width, color, front: bool = True):
    corners = vehicle_corners(x, y, heading, length, width)
    px, py = view.to_pixels(corners[:, 0], corners[:, 1])
    pts = list(zip(px.tolist(), py.tolist()))
    draw.polygon(pts, fill=color, outline=COLORS["outline"])
    if front:  # a dark bar across the front 0.6 m of the car: its direction
        bar = vehicle_corners(x, y, heading, length, width)
        u = np.array([math.cos(heading), math.sin(heading)])
        bar[0], bar[3] = bar[1] - FRONT_BAR * u, bar[2] - FRONT_BAR * u
        bx, by = view.to_pixels(bar[:, 0], bar[:, 1])
        draw.polygon(list(zip(bx.tolist(), by.tolist())), fill=COLORS["outline"])


ROLES = ("leader", "follower", "traffic")


def draw_vehicle(img, view: View, x: float, y: float, heading: float, role: str, crashed: bool = False):
    """Draw one car (``role`` "leader", "follower" or "traffic") onto ``img`` in place."""
    from PIL import ImageDraw

    if role not in ROLES:
        raise ValueError(f"role must be one of {', '.join(map(repr, ROLES))}, got {role!r}")
    color = COLORS["crashed"] if crashed else COLORS[role]
    _draw_box(ImageDraw.Draw(img), view, x, y, heading, VEHICLE_LENGTH, VEHICLE_WIDTH, color)
    return img


def vehicle_roles(num_vehicles: int, controlled=(0, 1)) -> list[str]:
    """Each slot's role: the first controlled slot leads, the other agents follow, every other slot is traffic."""
    roles = ["traffic"] * num_vehicles
    for j, i in enumerate(controlled):
        roles[i] = "leader" if j == 0 else "follower"
    return roles


def draw_frame(background, view: View, x, y, heading, crashed, caption: str | None = None, roles=None,
               alive=None):
    """One frame: a copy of ``background`` with every alive vehicle and a caption. ``roles`` per vehicle
    (default: index 0 leader, 1 follower); traffic is drawn first, then the followers, the leader on top."""
    from PIL import ImageDraw

    roles = vehicle_roles(len(x)) if roles is None else roles
    alive = np.ones(len(x), bool) if alive is None else np.asarray(alive, bool)
    img = background.copy()
    for role in ("traffic", "follower", "leader"):
        for i in np.flatnonzero(alive & (np.asarray(roles) == role))[::-1]:
            draw_vehicle(img, view, float(x[i]), float(y[i]), float(heading[i]), role, bool(crashed[i]))
    if caption:
        ImageDraw.Draw(img).text((6, 4), caption, fill=COLORS["text"])
    return img


# ---------------------------------------------------------------------------------------------------------
# Simulation (jitted) and frames
