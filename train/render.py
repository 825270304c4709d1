"""Render a policy's episode: the road from the JAX lane table, the agents (leader, followers) and any background
traffic, crashes; GIF (and MP4 with ffmpeg).

```
python -m train.render --checkpoint runs/merge_csq --seed 0           # greedy episode of seed 0's agent
python -m train.render --scenario racetrack --policy random --out r.gif
python -m train.render --scenario highway --agents 3 --policy idle    # a training scenario with K agents
python -m train.render --scenario intersection-v1 --policy random     # any envs_jax traffic task
```

The episode is simulated in one jitted ``lax.scan`` (every simulation frame is kept through
``env.step_substeps``); drawing happens afterwards on the host with Pillow (:mod:`train.drawing`).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from train.drawing import WHOLE_ROAD_EXTENT, View, draw_frame, draw_road, fit_view, road_bounds, vehicle_roles
from train.episode_record import simple_policy, simulate
from train.video import frame_indices, write_gif, write_mp4

__all__ = ["episode_frames", "render_episode", "render_checkpoint", "load_checkpoint_policy", "scenario_env", "main"]


FOLLOW_BELOW_SCALE = 2.0  # px/m: when the agents' whole path would be drawn smaller, the camera follows them
FOLLOW_SCALE, FOLLOW_WIDTH = 4.0, 960  # the following camera: px/m and frame width (240 m of road)


def episode_frames(env, params, rec: dict, stride: int = 3, view: View | None = None, title: str = ""):
    """Pillow frames of a simulated episode (``simulate``), every ``stride``-th simulation frame. Without a
    ``view``: one fixed view of the agents' paths (and of the whole road when it is compact) or, where those paths
    are long (highway), a camera that follows the leader (as highway-env's viewer follows its first vehicle).
    Returns the frames and the first's view."""
    controlled = list(rec["controlled"])
    follow = False
    if view is None:
        shown = rec["alive"][:, controlled]  # an agent absent from the episode (merge-cavs) has no path
        xs, ys = rec["x"][:, controlled][shown], rec["y"][:, controlled][shown]
        rx, ry = road_bounds(env.road)
        if max(rx[1] - rx[0], ry[1] - ry[0]) <= WHOLE_ROAD_EXTENT:  # compact road: show all of it
            xs, ys = np.concatenate([xs, rx]), np.concatenate([ys, ry])
        view = fit_view(xs, ys)
        if view.scale < FOLLOW_BELOW_SCALE:  # one canvas over the whole path, cropped around the agents per frame
            half = FOLLOW_WIDTH / (2 * FOLLOW_SCALE)
            ends = [xs.min() - half, xs.max() + half]
            view = fit_view(np.r_[xs, ends], np.r_[ys, ys[:2]], max_width=10**6, max_scale=FOLLOW_SCALE)
            follow = True
    background = draw_road(env.road, view, getattr(params, "obstacles", None))
    roles = vehicle_roles(rec["x"].shape[1], controlled)
    F = rec["frames_per_decision"]
    K = len(controlled)
    ret = np.concatenate([np.zeros((1, K)), np.cumsum(rec["reward"].reshape(-1, K), axis=0)])  # after each decision
    frames, views = [], []
    for j in frame_indices(len(rec["x"]), stride):
        d = j // F  # decisions completed at frame j
        t = j / env.simulation_frequency
        returns = (f"L {ret[d, 0]:6.1f}  F {ret[d, 1]:6.1f}" if K == 2
                   else " ".join(f"{r:5.1f}" for r in ret[d]))
        crash = rec["crashed"][j][controlled].any()
        caption = f"{title}  t={t:4.1f}s  return {returns}{'  CRASH' if crash else ''}"
        bg, v = background, view
        if follow:
            width = min(FOLLOW_WIDTH, view.width)
            cx = float(rec["x"][j][controlled[0]])
            left = int(np.clip(round((cx - view.origin_x) * view.scale - width / 2), 0, view.width - width))
            bg = background.crop((left, 0, left + width, view.height))
            v = View(view.origin_x + left / view.scale, view.origin_y, view.scale, width, view.height)
        views.append(v)
        frames.append(draw_frame(bg, v, rec["x"][j], rec["y"][j], rec["heading"][j], rec["crashed"][j],
                                 caption.strip(), roles, rec["alive"][j]))
    return frames, views[0]


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
    from train.env_params import with_values
    from train.restore import restore_run

    n = int(read_run_config(run_dir)["num_seeds"])  # a bad seed fails before anything is loaded
    if not 0 <= seed < n:
        raise ValueError(f"--seed must be a seed index of the run, 0..{n - 1}, got {seed}")
    config, trainer, state, _ = restore_run(run_dir, step)
    agent_state = jax.tree.map(lambda x: jnp.asarray(x[seed]), state.agent)
    agent = trainer.agent
    env = trainer.env
    if hasattr(env, "controlled"):  # traffic envs: the agents see their observation flattened, as in training
        policy = lambda key, obs: agent.greedy_act(agent_state, obs.reshape(obs.shape[:1] + (-1,)))
    else:
        policy = lambda key, obs: agent.greedy_act(agent_state, obs)
    return env, with_values(config["scenario"], env.default_params, config["env"]), policy, config


def render_checkpoint(run_dir: str, out: str | None = None, seed: int = 0, stride: int = 3, mp4: bool = True,
                      step: int | None = None) -> dict:
    """Greedy episode of seed ``seed``'s agent of run ``run_dir`` (default ``RUN_DIR/episode_seed<i>.gif``)."""
    env, params, policy, config = load_checkpoint_policy(run_dir, seed, step)
    out = out or os.path.join(run_dir, f"episode_seed{seed}.gif")
    title = f"{config['scenario']} {config['algo']} seed {seed}"
    return render_episode(env, params, policy, out, seed=seed, stride=stride, title=title, mp4=mp4)


# ---------------------------------------------------------------------------------------------------------
# Command line


def scenario_env(name: str, agents: int | None = None):
    """``(env, params)`` of a training scenario (as ``python -m train --scenario NAME --agents K`` builds it) or of
    an :mod:`envs_jax` traffic task with ``agents`` controlled vehicles."""
    import envs_jax
    from train.config import SCENARIO_AGENTS, SCENARIOS
    from train.trainer import make_env

    if name in SCENARIOS:
        default, lo, hi = SCENARIO_AGENTS[name]
        if agents is not None and not lo <= agents <= hi:
            raise ValueError(f"--agents for {name} must be {lo}..{hi}, got {agents}")
        env, _, params = make_env(name, agents)
        return env, params
    if name in envs_jax.available_tasks():
        env = envs_jax.make(name) if agents is None else envs_jax.make(name, controlled_vehicles=agents)
        return env, env.default_params
    raise ValueError(f"unknown scenario {name!r}; choose a training scenario ({', '.join(SCENARIOS)}) or a "
                     f"traffic task ({', '.join(envs_jax.available_tasks())})")


def parse_args(argv=None):
    p = argparse.ArgumentParser(prog="python -m train.render", description=(
        "Render one episode as a GIF (and an MP4 beside it when ffmpeg is installed): a trained run's greedy "
        "policy (--checkpoint RUN_DIR) or a simple policy on a scenario (--scenario NAME --policy random|idle)."))
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--checkpoint", metavar="RUN_DIR", help="run folder written by python -m train")
    src.add_argument("--scenario", help="a training scenario (python -m train --scenario: merge, roundabout, "
                     "intersection, racetrack, highway, merge-v0, merge-cavs, racetrack-v0) or an envs_jax traffic "
                     "task (e.g. intersection-v1, roundabout-v0), with --policy")
    p.add_argument("--agents", type=int, default=None, metavar="K",
                   help="with --scenario: controlled vehicles (default: the scenario's)")
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
            if args.agents is not None:
                raise ValueError("--agents applies to --scenario: a checkpoint's run fixes its number of agents")
            res = render_checkpoint(args.checkpoint, args.out, args.seed, args.stride, not args.no_mp4)
        else:
            env, params = scenario_env(args.scenario, args.agents)
            policy = simple_policy(env, args.policy)
            out = args.out or os.path.join("runs", "render", f"{args.scenario}_{args.policy}_seed{args.seed}.gif")
            res = render_episode(env, params, policy, out, seed=args.seed, stride=args.stride,
                                 title=f"{args.scenario} {args.policy}", mp4=not args.no_mp4)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    rec = res["record"]
    ret = rec["reward"].reshape(rec["n"], -1).sum(0)
    returns = f"L {ret[0]:.1f} F {ret[1]:.1f}" if len(ret) == 2 else " ".join(f"{r:.1f}" for r in ret)
    crash = rec["crashed"][-1][list(rec["controlled"])].any()
    print(f"wrote {', '.join(res['paths'])}: {res['frames']} frames at {res['fps']:g} fps; {rec['n']} decisions, "
          f"return {returns}, crash {'yes' if crash else 'no'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
