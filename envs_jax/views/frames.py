"""RGB frames of a simulator state for the host views' ``render()``, drawn by ``train/render.py``.

The road is drawn once (Pillow, highway-env's look) and the cars on top of it every call:
agent 0 in the leader's colour, the others in the follower's, red once crashed. Compact roads
(intersection, racetrack) are shown whole; long ones (merge, roundabout's approaches) in a
window around the cars. ``train.render`` and Pillow are imported on the first frame only.
"""

from __future__ import annotations

import numpy as np


class FrameRenderer:
    """``renderer(state) -> uint8 [H, W, 3]`` for one environment and its params."""

    def __init__(self, env, params):
        self.env = env
        self.params = params
        self._fixed = None  # (view, background) when the whole road fits

    def __call__(self, state) -> np.ndarray:
        from train import render as R

        x, y = np.asarray(state.x, np.float64), np.asarray(state.y, np.float64)
        heading, crashed = np.asarray(state.heading, np.float64), np.asarray(state.crashed, bool)
        if self._fixed is not None:
            view, background = self._fixed
        else:
            (x0, x1), (y0, y1) = R.road_bounds(self.env.road)
            if max(x1 - x0, y1 - y0) <= R.WHOLE_ROAD_EXTENT:
                view = R.fit_view(np.array([x0, x1]), np.array([y0, y1]))
                background = R.draw_road(self.env.road, view, self.params.obstacles)
                self._fixed = (view, background)
            else:
                view = R.fit_view(x, y, margin=40.0, min_extent=120.0)
                background = R.draw_road(self.env.road, view, self.params.obstacles)
        img = background.copy()
        for i in reversed(range(len(x))):  # agent 0 drawn last, on top
            R.draw_vehicle(img, view, float(x[i]), float(y[i]), float(heading[i]),
                           "leader" if i == 0 else "follower", bool(crashed[i]))
        return np.asarray(img, dtype=np.uint8)
