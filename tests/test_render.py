"""The renderer against known geometry: lane markings, car rectangles and colours at a known world->pixel map;
a GIF of a random-policy episode with the right number of frames, checked against an eager replay."""

import math

import jax
import numpy as np
import pytest

pytest.importorskip("PIL")
from PIL import Image  # noqa: E402

import envs_jax  # noqa: E402
from envs_jax import lanes as L  # noqa: E402
from envs_jax.road import RoadNetwork  # noqa: E402
from train import drawing, episode_record, render  # noqa: E402
from train.video import frame_indices  # noqa: E402

BG, ROAD, WHITE = drawing.COLORS["background"], drawing.COLORS["road"], drawing.COLORS["marking"]


def _road(*specs):
    net = RoadNetwork()
    for i, spec in enumerate(specs):
        net.add_lane(f"a{i}", f"b{i}", spec)
    return net.freeze()


def test_straight_lane_markings_at_known_pixels():
    # Lane from (0, 0) to (40, 0), width 4: left side (lat -2, world y = -2) continuous line, right side
    # (y = +2) striped. View: origin (-5, -10), 4 px/m -> pixel = ((x + 5) * 4, (y + 10) * 4).
    road = _road(L.straight([0, 0], [40, 0], line_types=(L.LINE_CONTINUOUS_LINE, L.LINE_STRIPED)))
    view = drawing.View(-5.0, -10.0, 4.0, 200, 80)
    img = np.asarray(drawing.draw_road(road, view))
    px = lambda x: int((x + 5) * 4)
    row_left, row_right, row_center = 32, 48, 40  # y = -2, +2, 0
    # continuous line along the whole lane (s = 0.5 .. 39.5), nothing beyond its end
    for x in np.arange(0.5, 39.6, 1.0):
        assert tuple(img[row_left, px(x)]) == WHITE, x
    assert tuple(img[row_left, px(43)]) == BG
    # stripes: 3 m painted every 4.33 m from s = 0; mid-stripe white, mid-gap road grey
    for k in range(9):
        s_on, s_off = k * 4.33 + 1.5, k * 4.33 + 3.66
        assert tuple(img[row_right, px(s_on)]) == WHITE, s_on
        assert tuple(img[row_right, px(s_off)]) == ROAD, s_off
    # lane surface between the lines, off-road outside
    assert tuple(img[row_center, px(20)]) == ROAD
    assert tuple(img[row_left - 8, px(20)]) == BG and tuple(img[row_right + 8, px(20)]) == BG
    # exactly one white row per side (0.3 m * 4 px/m -> 1 px wide lines)
    col = img[:, px(4 * 4.33 + 1.5)]  # mid-stripe
    assert [r for r in range(80) if tuple(col[r]) == WHITE] == [row_left, row_right]


def test_continuous_and_none_line_types_and_vertical_lane():
    # A northbound lane x = 10, y from 30 down to 0 (heading -90 deg): its left side (lat -2) lies at
    # x = 10 + 2 = 12 ... lateral = (-dir_y, dir_x) = (1, 0), so lat -2 -> x = 8, lat +2 -> x = 12.
    road = _road(L.straight([10, 30], [10, 0], line_types=(L.LINE_CONTINUOUS, L.LINE_NONE)))
    view = drawing.View(0.0, -5.0, 5.0, 100, 200)
    img = np.asarray(drawing.draw_road(road, view))
    col_left = int(8 * 5)
    for y in np.arange(0.5, 29.6, 0.5):
        assert tuple(img[int((y + 5) * 5), col_left]) == WHITE, y  # CONTINUOUS: no gaps
    assert not np.any(np.all(img[:, col_left + 3:] == WHITE, axis=-1))  # NONE: no marking at all on the right
    assert tuple(img[int(15 * 5), int(10 * 5)]) == ROAD


def test_circular_lane_marking_lies_on_the_circle():
    # Counter-clockwise arc (clockwise=False), radius 20 around (0, 0), continuous on both sides: every white
    # pixel lies within a pixel of radius 18 or 22 (chords of 4.33 m deviate by < 0.12 m).
    road = _road(L.circular([0, 0], 20, 0.0, -np.pi / 2, clockwise=False,
                            line_types=(L.LINE_CONTINUOUS, L.LINE_CONTINUOUS)))
    view = drawing.View(-30.0, -30.0, 4.0, 240, 240)
    img = np.asarray(drawing.draw_road(road, view))
    rows, cols = np.nonzero(np.all(img == WHITE, axis=-1))
    r = np.hypot((cols + 0.5) / 4 - 30, (rows + 0.5) / 4 - 30)
    assert rows.size > 100
    assert np.all((np.abs(r - 18) < 0.4) | (np.abs(r - 22) < 0.4))
    assert np.any(np.abs(r - 18) < 0.4) and np.any(np.abs(r - 22) < 0.4)


@pytest.mark.parametrize("heading_deg", [0.0, 30.0, -120.0])
def test_vehicle_rectangle_pixels_at_known_pose(heading_deg):
    h = math.radians(heading_deg)
    view = drawing.View(0.0, 0.0, 10.0, 200, 200)
    img = np.asarray(drawing.draw_vehicle(Image.new("RGB", (200, 200), BG), view, 10.0, 10.0, h, "leader"))
    # Independent point-in-rectangle test for every pixel centre (in pixels: centre (100, 100), 50 x 20 px).
    jj, ii = np.mgrid[0:200, 0:200]
    dx, dy = ii + 0.5 - 100, jj + 0.5 - 100
    lon = dx * math.cos(h) + dy * math.sin(h)
    lat = -dx * math.sin(h) + dy * math.cos(h)
    # Clear of the edges and the front bar.
    inside = (np.abs(lon) < 25 - 1.5) & (np.abs(lat) < 10 - 1.5) & (lon < 25 - 6 - 1.5)
    outside = (np.abs(lon) > 25 + 1.5) | (np.abs(lat) > 10 + 1.5)
    colour = lambda c: np.all(img == np.array(c), axis=-1)
    assert colour(drawing.COLORS["leader"])[inside].all()
    assert colour(BG)[outside].all()
    # the dark front bar sits at the heading's end, not at the rear
    front = (int(100 + 24 * math.cos(h)), int(100 + 24 * math.sin(h)))
    rear = (int(100 - 23 * math.cos(h)), int(100 - 23 * math.sin(h)))
    assert tuple(img[front[1], front[0]]) == drawing.COLORS["outline"]
    assert tuple(img[rear[1], rear[0]]) == drawing.COLORS["leader"]


def test_roles_and_crash_colours():
    view = drawing.View(0.0, 0.0, 10.0, 100, 60)
    bg = Image.new("RGB", (100, 60), BG)
    frame = np.asarray(drawing.draw_frame(bg, view, [2.5, 7.0], [3.0, 3.0], [0.0, 0.0], [False, True]))
    assert tuple(frame[30, 20]) == drawing.COLORS["leader"]  # (2.0 m, 3.0 m)
    assert tuple(frame[30, 65]) == drawing.COLORS["crashed"]  # the crashed follower at (6.5 m, 3.0 m)
    frame = np.asarray(drawing.draw_frame(bg, view, [2.5, 7.0], [3.0, 3.0], [0.0, 0.0], [False, False]))
    assert tuple(frame[30, 65]) == drawing.COLORS["follower"]
    with pytest.raises(ValueError, match="role must be"):
        drawing.draw_vehicle(bg, view, 0, 0, 0, "ego")
    # K agents among traffic: roles by slot, dead slots left out, traffic under the agents
    roles = drawing.vehicle_roles(4, controlled=(2, 0))
    assert roles == ["follower", "traffic", "leader", "traffic"]
    frame = np.asarray(drawing.draw_frame(bg, view, [2.5, 7.0, 2.5, 2.5], [3.0, 3.0, 3.0, 5.5], [0.0] * 4,
                                          [False] * 4, roles=roles, alive=[True, True, True, False]))
    assert tuple(frame[30, 20]) == drawing.COLORS["leader"]  # slot 2 drawn over slot 0 at the same place
    assert tuple(frame[30, 65]) == drawing.COLORS["traffic"]
    assert tuple(frame[50, 25]) == BG  # the dead slot, centred at (2.5 m, 5.5 m), is not drawn


def test_fit_view_contains_points_and_keeps_scale():
    v = drawing.fit_view([0, 100], [0, 10], margin=10, min_extent=60, max_width=600, max_height=600, max_scale=8)
    assert v.width % 2 == 0 and v.height % 2 == 0 and v.width <= 600
    assert v.scale == pytest.approx(600 / 120)
    px, py = v.to_pixels([0, 100], [0, 10])
    assert np.all((px > 0) & (px < v.width) & (py > 0) & (py < v.height))
    with pytest.raises(ValueError, match="finite point"):
        drawing.fit_view([np.nan], [np.nan])


def test_random_episode_gif_has_one_frame_per_stride_and_replays_eagerly(tmp_path):
    env = envs_jax.make("merge")
    params = env.default_params
    out = str(tmp_path / "merge.gif")
    res = render.render_episode(env, params, episode_record.simple_policy(env, "random"), out, seed=3, stride=4,
                                mp4=False)
    rec = res["record"]
    n, F = rec["n"], env.frames
    assert len(rec["x"]) == 1 + n * F
    expected = len(range(0, 1 + n * F, 4)) + (0 if (n * F) % 4 == 0 else 1)  # every 4th frame + the last one
    gif = Image.open(out)
    assert gif.n_frames == res["frames"] == expected
    assert gif.size == (res["view"].width, res["view"].height)
    # Replay the recorded actions eagerly: the episode ends exactly after n decisions, at the same positions.
    obs, state = env.reset(jax.random.split(jax.random.PRNGKey(3))[0], params)
    for t in range(n):
        obs, state, reward, cost, done, info = env.step(jax.random.PRNGKey(t), state, rec["action"][t], params)
        np.testing.assert_allclose(np.asarray(state.x), rec["x"][(t + 1) * F], rtol=1e-6)
        np.testing.assert_allclose(np.asarray(reward), rec["reward"][t], rtol=1e-6)
        assert bool(done) == (t == n - 1)
    # the first GIF frame shows the leader at its start pose in the leader colour
    gif.seek(0)
    first = np.asarray(gif.convert("RGB"))
    px, py = res["view"].to_pixels(rec["x"][0, 0], rec["y"][0, 0])
    assert np.abs(first[int(py), int(px) - 3].astype(int) - drawing.COLORS["leader"]).max() <= 8


def test_cli_errors_exit_2(capsys, tmp_path):
    assert render.main(["--scenario", "highway-v9"]) == 2
    assert "error: unknown scenario 'highway-v9'; choose a training scenario" in capsys.readouterr().err
    assert render.main(["--scenario", "merge-cavs", "--agents", "5"]) == 2
    assert "--agents for merge-cavs must be 3..4" in capsys.readouterr().err
    assert render.main(["--scenario", "merge-v0", "--agents", "9"]) == 2
    assert "--agents for merge-v0 must be 2..8" in capsys.readouterr().err
    assert render.main(["--checkpoint", str(tmp_path), "--agents", "3"]) == 2
    assert "--agents applies to --scenario" in capsys.readouterr().err
    assert render.main(["--scenario", "merge", "--policy", "fast"]) == 2
    assert "unknown policy 'fast'" in capsys.readouterr().err
    assert render.main(["--checkpoint", str(tmp_path)]) == 2
    assert "is not a run folder" in capsys.readouterr().err
    assert render.main(["--scenario", "merge", "--out", str(tmp_path / "x.png")]) == 2
    assert "must end in .gif or .mp4" in capsys.readouterr().err


@pytest.mark.parametrize("scenario", ["merge", "roundabout"])
def test_batched_lane_geometry_matches_pointwise_lane_positions(scenario):
    """The road's surfaces and markings come from one padded, jitted batch per lane table; every point must be
    the lane's own position() evaluated point by point (straight, sine and circular lanes)."""
    lanes = envs_jax.make(scenario).road.lanes
    polys = drawing.lane_surfaces(lanes, step=7.0)
    width, length = lanes.np_col("width"), lanes.np_col("length")
    for i in sorted({0, lanes.size // 2, lanes.size - 1}):
        k = len(polys[i]) // 2
        s = np.linspace(0.0, length[i], k)
        for j in (0, k // 2, k - 1):
            for lat, (x, y) in ((-width[i] / 2, polys[i][j]), (width[i] / 2, polys[i][-1 - j])):
                px, py = L.position(lanes, i, float(s[j]), float(lat))
                np.testing.assert_allclose([x, y], [float(px), float(py)], atol=1e-3)
    segs = drawing.marking_segments(lanes)
    assert len(segs) > 0 and np.isfinite(np.asarray(segs)).all()
    x0, y0, x1, y1 = segs[-1]
    assert math.hypot(x1 - x0, y1 - y0) > 0.5 * drawing.STRIPE_LENGTH


def _pixel_colour(img, view, x, y):
    px, py = view.to_pixels(x, y)
    return tuple(int(c) for c in img[int(py), int(px)])


def test_traffic_task_frames_show_agents_and_traffic_in_their_roles(tmp_path):
    """merge-v0 with three agents among IDM traffic: the record covers every slot, replays eagerly, and the first
    frame shows each uncovered alive vehicle's centre in its role's colour."""
    env, params = render.scenario_env("merge-v0", 3)
    res = render.render_episode(env, params, episode_record.simple_policy(env, "idle"), str(tmp_path / "m.gif"),
                                seed=1, stride=5, mp4=False)
    rec, F = res["record"], env.frames
    V = env.num_slots
    assert rec["x"].shape == (1 + rec["n"] * F, V) and rec["alive"].shape == rec["x"].shape
    assert rec["reward"].shape == (rec["n"], 3) and rec["controlled"] == tuple(env.controlled)
    obs, state = env.reset(jax.random.split(jax.random.PRNGKey(1))[0], params)
    for t in range(min(rec["n"], 4)):
        obs, state, reward, cost, done, info = env.step(jax.random.PRNGKey(t), state, rec["action"][t], params)
        np.testing.assert_allclose(np.asarray(state.x), rec["x"][(t + 1) * F], rtol=1e-6)
        np.testing.assert_allclose(np.asarray(reward), rec["reward"][t], rtol=1e-6)
    gif = Image.open(str(tmp_path / "m.gif"))
    first = np.asarray(gif.convert("RGB"))
    roles = drawing.vehicle_roles(V, rec["controlled"])
    x, y, alive = rec["x"][0], rec["y"][0], rec["alive"][0]
    checked = set()
    px, py = res["view"].to_pixels(x, y)
    inside = (px > 10) & (px < res["view"].width - 10) & (py > 10) & (py < res["view"].height - 10)
    for i in np.flatnonzero(alive & inside):
        others = np.flatnonzero(alive & (np.arange(V) != i))
        if (np.hypot(x[others] - x[i], y[others] - y[i]) > 3.0).all():  # no other car covers its centre
            got = np.asarray(_pixel_colour(first, res["view"], x[i], y[i]))
            assert np.abs(got - drawing.COLORS[roles[i]]).max() <= 8, (i, roles[i], got)  # GIF palette
            checked.add(roles[i])
    assert checked == {"leader", "follower", "traffic"}


def test_long_roads_get_a_camera_that_follows_the_leader(tmp_path):
    env, params = render.scenario_env("highway", 2)
    rec = episode_record.simulate(env, params, episode_record.simple_policy(env, "idle"), jax.random.PRNGKey(0),
                                  max_steps=12)
    frames, view = render.episode_frames(env, params, rec, stride=10)
    assert view.scale == render.FOLLOW_SCALE and view.width == render.FOLLOW_WIDTH
    lead = rec["controlled"][0]
    for f, j in zip(frames, frame_indices(len(rec["x"]), 10)):
        assert f.size == (render.FOLLOW_WIDTH, view.height)
        img = np.asarray(f)
        # the leader sits mid-frame (its centre within a pixel of the middle), in the leader colour
        cx = render.FOLLOW_WIDTH // 2
        py = (rec["y"][j, lead] - view.origin_y) * view.scale
        colour = drawing.COLORS["crashed"] if rec["crashed"][j, lead] else drawing.COLORS["leader"]
        assert colour in {tuple(int(c) for c in img[int(py), px]) for px in (cx - 1, cx, cx + 1)}
