"""Frames to files: an animated GIF with Pillow, an H.264 MP4 through the ``ffmpeg`` executable.
"""

from __future__ import annotations

import os
import shutil
import subprocess

import numpy as np

__all__ = ["frame_indices", "write_gif", "write_mp4"]


def frame_indices(num_frames: int, stride: int) -> np.ndarray:
    """Every ``stride``-th frame from the first, plus the last one."""
    if stride < 1:
        raise ValueError(f"frame stride must be >= 1, got {stride}")
    idx = np.arange(0, num_frames, stride)
    if idx[-1] != num_frames - 1:
        idx = np.append(idx, num_frames - 1)
    return idx


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
