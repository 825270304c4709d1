"""Render a policy's episode: the road from the JAX lane table, the two cars, crashes; GIF (and MP4 with ffmpeg).

```
python -m train.render --checkpoint runs/merge_csq --seed 0           # greedy episode of seed 0's agent
python -m train.render --scenario racetrack --policy random --out r.gif
```

The episode is simulated in one jitted ``lax.scan`` (every simulation frame is kept through
``env.step_substeps``); drawing happens afterwards on the host with Pillow.

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

import argparse
import dataclasses
import math
import os
import shutil
import subprocess
import sys
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from envs_jax.time_limit import step_limit

__all__ = ["View", "fit_view", "draw_road", "draw_vehicle", "draw_frame", "simulate", "episode_frames",
           "write_gif", "write_mp4", "render_episode", "render_checkpoint", "load_checkpoint_policy",
           "simple_policy", "COLORS", "main"]

VEHICLE_LENGTH, VEHICLE_WIDTH = 5.0, 2.0
FRONT_BAR = 0.6  # metres of the car's front drawn dark
STRIPE_SPACING, STRIPE_LENGTH, STRIPE_WIDTH = 4.33, 3.0, 0.3  # highway-env LaneGraphics

COLORS = {
    "background": (96, 140, 84),  # off-road
    "road": (100, 100, 100),  # highway-env's GREY
    "marking": (255, 255, 255),
    "leader": (50, 200, 0),  # highway-env EGO_COLOR (GREEN)
    "follower": (100, 200, 255),  # highway-env BLUE
    "crashed": (255, 100, 100),  # highway-env RED
    "outline": (60, 60, 60),  # highway-env BLACK
    "obstacle": (200, 200, 0),  # highway-env YELLOW
    "text": (255, 255, 255),
}

POLICIES = ("random", "idle")


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


def draw_vehicle(img, view: View, x: float, y: float, heading: float, role: str, crashed: bool = False):
    """Draw one car (``role`` "leader" or "follower") onto ``img`` in place."""
    from PIL import ImageDraw

    if role not in ("leader", "follower"):
        raise ValueError(f"role must be 'leader' or 'follower', got {role!r}")
    color = COLORS["crashed"] if crashed else COLORS[role]
    _draw_box(ImageDraw.Draw(img), view, x, y, heading, VEHICLE_LENGTH, VEHICLE_WIDTH, color)
    return img


def draw_frame(background, view: View, x, y, heading, crashed, caption: str | None = None):
    """One frame: a copy of ``background`` with both cars (index 0 leader, 1 follower) and a caption."""
    from PIL import ImageDraw

    img = background.copy()
    for i, role in ((1, "follower"), (0, "leader")):  # leader on top
        draw_vehicle(img, view, float(x[i]), float(y[i]), float(heading[i]), role, bool(crashed[i]))
    if caption:
        ImageDraw.Draw(img).text((6, 4), caption, fill=COLORS["text"])
    return img


# ---------------------------------------------------------------------------------------------------------
# Simulation (jitted) and frames


def simple_policy(env, name: str) -> Callable:
    """``(key, obs) -> action``: ``random`` (uniform) or ``idle`` (IDLE meta-action / zero continuous action)."""
    from envs_jax.wrappers import random_actions

    if name == "random":
        return random_actions(env)
    if name == "idle":
        if env.discrete:
            return lambda key, obs: jnp.ones(env.action_shape, jnp.int32)  # 1 = IDLE
        return lambda key, obs: jnp.zeros(env.action_shape, jnp.float32)
    raise ValueError(f"unknown policy {name!r}; choose one of {', '.join(POLICIES)} (or pass --checkpoint RUN_DIR)")


def max_decisions(env, params) -> int:
    """The time limit in policy steps: ``ceil(duration * policy_frequency)`` (:mod:`envs_jax.time_limit`)."""
    return int(step_limit(float(params.duration), env.policy_frequency))


def simulate(env, params, policy: Callable, key, max_steps: int | None = None) -> dict:
    """One episode from ``reset(split(key)[0])``, in one jitted scan; numpy arrays on return.

    Returns ``x, y, heading, speed, crashed, on_road`` as ``[1 + n * frames, 2]`` (the reset state, then every
    simulation frame of the ``n`` decisions until ``done``), ``action`` ``[n, ...]``, ``reward``, ``cost``
    ``[n, 2]``, ``done`` ``[n]`` and ``n``.
    """
    T = max_decisions(env, params) if max_steps is None else int(max_steps)
    k_reset, k_run = jax.random.split(key)

    @jax.jit
    def run(k_reset, k_run):
        obs, state = env.reset(k_reset, params)

        def body(carry, k):
            obs, state, over = carry
            k_act, k_step = jax.random.split(k)
            action = policy(k_act, obs)
            obs2, state2, reward, cost, done, info, traj = env.step_substeps(k_step, state, action, params)
            out = dict(action=action, reward=reward, cost=cost, done=done, live=~over,
                       frames={k: traj[k] for k in ("x", "y", "heading", "speed", "crashed", "on_road")})
            return (obs2, state2, over | done), out

        _, outs = jax.lax.scan(body, (obs, state, jnp.zeros((), bool)), jax.random.split(k_run, T))
        first = {"x": state.x, "y": state.y, "heading": state.heading, "speed": state.speed,
                 "crashed": state.crashed, "on_road": state.on_road}
        return first, outs

    first, outs = jax.device_get(run(k_reset, k_run))
    n = int(np.sum(outs["live"]))
    rec = {}
    for k, v in first.items():
        frames = np.asarray(outs["frames"][k])[:n]  # [n, F, 2]
        rec[k] = np.concatenate([np.asarray(v)[None], frames.reshape((-1,) + frames.shape[2:])])
    for k in ("action", "reward", "cost", "done"):
        rec[k] = np.asarray(outs[k])[:n]
    rec["n"] = n
    rec["frames_per_decision"] = env.frames
    return rec


def frame_indices(num_frames: int, stride: int) -> np.ndarray:
    """Every ``stride``-th frame from the first, plus the last one."""
    if stride < 1:
        raise ValueError(f"frame stride must be >= 1, got {stride}")
    idx = np.arange(0, num_frames, stride)
    if idx[-1] != num_frames - 1:
        idx = np.append(idx, num_frames - 1)
    return idx


def episode_frames(env, params, rec: dict, stride: int = 3, view: View | None = None, title: str = ""):
    """Pillow frames of a simulated episode (``simulate``), every ``stride``-th simulation frame."""
    if view is None:
        xs, ys = rec["x"].ravel(), rec["y"].ravel()
        rx, ry = road_bounds(env.road)
        if max(rx[1] - rx[0], ry[1] - ry[0]) <= WHOLE_ROAD_EXTENT:  # compact road: show all of it
            xs, ys = np.concatenate([xs, rx]), np.concatenate([ys, ry])
        view = fit_view(xs, ys)
    background = draw_road(env.road, view, params.obstacles)
    F = rec["frames_per_decision"]
    ret = np.concatenate([np.zeros((1, 2)), np.cumsum(rec["reward"], axis=0)])  # return after each decision
    frames = []
    for j in frame_indices(len(rec["x"]), stride):
        d = j // F  # decisions completed at frame j
        t = j / env.simulation_frequency
        caption = (f"{title}  t={t:4.1f}s  return L {ret[d, 0]:6.1f}  F {ret[d, 1]:6.1f}"
                   f"{'  CRASH' if rec['crashed'][j].any() else ''}")
        frames.append(draw_frame(background, view, rec["x"][j], rec["y"][j], rec["heading"][j], rec["crashed"][j],
                                 caption.strip()))
    return frames, view


def write_gif(frames, path: str, fps: float) -> str:
    if not frames:
        raise ValueError("no frames to write")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp.gif"
    frames[0].save(tmp, save_all=True, append_images=frames[1:], duration=int(round(1000 / fps)), loop=0,
                   optimize=False)
    os.replace(tmp, path)
    return path


def write_mp4(frames, path: str, fps: float) -> str | None:
    """H.264 MP4 through the ``ffmpeg`` executable; None (nothing written) when ffmpeg is not installed."""
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None or not frames:
        return None
    w, h = frames[0].size
    cmd = [ffmpeg, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{w}x{h}",
           "-r", f"{fps:g}", "-i", "-", "-pix_fmt", "yuv420p", "-vcodec", "libx264", path]
    proc = subprocess.Popen(cmd, stdin=subprocess.PIPE)
    for f in frames:
        proc.stdin.write(f.convert("RGB").tobytes())
    proc.stdin.close()
    if proc.wait() != 0:
        raise RuntimeError(f"ffmpeg failed writing {path}")
    return path


def render_episode(env, params, policy: Callable, out: str, seed: int = 0, stride: int = 3, title: str = "",
                   mp4: bool = True) -> dict:
    """Simulate one episode of ``policy`` and write ``out`` (.gif, or .mp4 which needs ffmpeg); with ``mp4`` a
    .gif is accompanied by an .mp4 when ffmpeg is available. Returns the paths, frame count and episode record."""
    if not out.endswith((".gif", ".mp4")):
        raise ValueError(f"--out must end in .gif or .mp4, got {out!r}")
    if out.endswith(".mp4") and shutil.which("ffmpeg") is None:
        raise ValueError("writing .mp4 needs the ffmpeg executable on PATH; install it or write a .gif")
    rec = simulate(env, params, policy, jax.random.PRNGKey(seed))
    frames, view = episode_frames(env, params, rec, stride, title=title)
    fps = env.simulation_frequency / stride
    paths = []
    if out.endswith(".gif"):
        paths.append(write_gif(frames, out, fps))
        if mp4:
            p = write_mp4(frames, out[:-4] + ".mp4", fps)
            if p:
                paths.append(p)
    else:
        paths.append(write_mp4(frames, out, fps))
    return {"paths": paths, "frames": len(frames), "fps": fps, "record": rec, "view": view}


# ---------------------------------------------------------------------------------------------------------
# Checkpoints


def load_checkpoint_policy(run_dir: str, seed: int = 0, step: int | None = None):
    """``(env, params, policy, config)`` for seed ``seed``'s greedy agent in run folder ``run_dir`` (newest
    checkpoint, or ``step``; :func:`train.restore.restore_run`)."""
    from train.config import read_run_config
    from train.restore import restore_run

    n = int(read_run_config(run_dir)["num_seeds"])  # a bad seed fails before anything is loaded
    if not 0 <= seed < n:
        raise ValueError(f"--seed must be a seed index of the run, 0..{n - 1}, got {seed}")
    config, trainer, state, _ = restore_run(run_dir, step)
    agent_state = jax.tree.map(lambda x: jnp.asarray(x[seed]), state.agent)
    agent = trainer.agent
    policy = lambda key, obs: agent.greedy_act(agent_state, obs)
    env = trainer.env
    return env, env.default_params, policy, config


def render_checkpoint(run_dir: str, out: str | None = None, seed: int = 0, stride: int = 3, mp4: bool = True,
                      step: int | None = None) -> dict:
    """Greedy episode of seed ``seed``'s agent of run ``run_dir`` (default ``RUN_DIR/episode_seed<i>.gif``)."""
    env, params, policy, config = load_checkpoint_policy(run_dir, seed, step)
    out = out or os.path.join(run_dir, f"episode_seed{seed}.gif")
    title = f"{config['scenario']} {config['algo']} seed {seed}"
    return render_episode(env, params, policy, out, seed=seed, stride=stride, title=title, mp4=mp4)


# ---------------------------------------------------------------------------------------------------------
# Command line


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="python -m train.render", description=(
        "Render one episode as a GIF (and an MP4 beside it when ffmpeg is installed): a trained run's greedy "
        "policy (--checkpoint RUN_DIR) or a simple policy on a scenario (--scenario NAME --policy random|idle)."))
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", metavar="RUN_DIR", help="run folder written by python -m train")
    src.add_argument("--scenario", help="merge | roundabout | intersection | racetrack (with --policy)")
    p.add_argument("--policy", default="random", help="without --checkpoint: random (default) | idle")
    p.add_argument("--seed", type=int, default=0,
                   help="with --checkpoint: which seed's agent (index); also seeds the episode (default 0)")
    p.add_argument("--out", default=None, help="output .gif or .mp4 (default RUN_DIR/episode_seed<i>.gif or "
                                               "runs/render/<scenario>_<policy>_seed<i>.gif)")
    p.add_argument("--stride", type=int, default=3,
                   help="draw every N-th simulation frame (default 3: 5 frames per simulated second, real time)")
    p.add_argument("--no-mp4", action="store_true", help="do not write an MP4 beside the GIF")
    return p.parse_args(argv)


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        if args.stride < 1:
            raise ValueError(f"--stride must be >= 1, got {args.stride}")
        if args.checkpoint:
            res = render_checkpoint(args.checkpoint, args.out, args.seed, args.stride, not args.no_mp4)
        else:
            import envs_jax

            if args.scenario not in envs_jax.available_scenarios():
                raise ValueError(f"unknown scenario {args.scenario!r}; choose one of "
                                 f"{', '.join(envs_jax.available_scenarios())}")
            env = envs_jax.make(args.scenario)
            policy = simple_policy(env, args.policy)
            out = args.out or os.path.join("runs", "render", f"{args.scenario}_{args.policy}_seed{args.seed}.gif")
            res = render_episode(env, env.default_params, policy, out, seed=args.seed, stride=args.stride,
                                 title=f"{args.scenario} {args.policy}", mp4=not args.no_mp4)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    rec = res["record"]
    print(f"wrote {', '.join(res['paths'])}: {res['frames']} frames at {res['fps']:g} fps; {rec['n']} decisions, "
          f"return L {rec['reward'][:, 0].sum():.1f} F {rec['reward'][:, 1].sum():.1f}, "
          f"crash {'yes' if rec['crashed'][-1].any() else 'no'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
