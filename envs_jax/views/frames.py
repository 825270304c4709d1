"""RGB frames of a simulator state for the host views' ``render()``, drawn by ``train/drawing.py``.

The road is drawn once (Pillow, highway-env's look) and the cars on top of it every call, as
highway-env colours them: the two-agent scenarios' agent 0 green and agent 1 blue; in the traffic
tasks every controlled car green (highway-env's ``MDPVehicle`` colour) and the background traffic
blue (its ``IDMVehicle`` colour), only the occupied vehicle slots; red once crashed. Compact roads
(intersection, racetrack) are shown whole; long ones (merge, roundabout's approaches, highway) in
a window around the controlled cars. ``train.drawing`` and Pillow are imported on the first frame only.
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
        from train import drawing as R

        x, y = np.asarray(state.x, np.float64), np.asarray(state.y, np.float64)
        heading, crashed = np.asarray(state.heading, np.float64), np.asarray(state.crashed, bool)
        alive = np.asarray(getattr(state, "alive", np.ones(x.shape, bool)), bool)
        controlled = getattr(self.env, "controlled", None)  # traffic tasks: the agents' vehicle slots
        if controlled is None:
            roles = ["leader" if i == 0 else "follower" for i in range(len(x))]
            agents = np.arange(len(x))
        else:
            agents = np.asarray(controlled, int)
            roles = ["follower"] * len(x)
            for i in agents:
                roles[i] = "leader"
        if self._fixed is not None:
            view, background = self._fixed
        else:
            (x0, x1), (y0, y1) = R.road_bounds(self.env.road)
            if max(x1 - x0, y1 - y0) <= R.WHOLE_ROAD_EXTENT:
                view = R.fit_view(np.array([x0, x1]), np.array([y0, y1]))
                background = R.draw_road(self.env.road, view, self.params.obstacles)
                self._fixed = (view, background)
            else:
                view = R.fit_view(x[agents], y[agents], margin=40.0, min_extent=120.0)
                background = R.draw_road(self.env.road, view, self.params.obstacles)
        img = background.copy()
        order = [i for i in range(len(x)) if i not in set(agents.tolist())] + agents[::-1].tolist()
        for i in order:  # traffic first, then the agents, agent 0 last (on top)
            if alive[i]:
                R.draw_vehicle(img, view, float(x[i]), float(y[i]), float(heading[i]), roles[i], bool(crashed[i]))
        return np.asarray(img, dtype=np.uint8)
