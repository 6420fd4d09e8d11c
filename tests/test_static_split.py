"""The still / moving split of a video's initial points (gsgs_engine.init.static_split) and the 4D init that uses it."""

from __future__ import annotations

import numpy as np
import pytest

from gsgs_engine.cameras import Camera, look_at
from gsgs_engine.init.static_split import camera_medians, moving_point_mask, moving_pixels
from gsgs_engine.io.scene import View

W = H = 32


def _camera(index: int, eye, frame: int, frames: int) -> Camera:
    R, t = look_at(eye, (0.0, 0.0, 0.0))
    return Camera(R=R, t=t, fx=30.0, fy=30.0, cx=W / 2, cy=H / 2, width=W, height=H, name=f"c{index}_f{frame}",
                  time=frame / (frames - 1), extra={"camera_index": index, "frame": frame})


def _video(frames: int = 3):
    """Two cameras on the x and y axes looking at the origin; a grey still background, and a white 4x4 px
    square that walks across each image from frame to frame."""
    eyes = [(4.0, 0.0, 0.0), (0.0, 4.0, 0.0)]
    by_frame = {}
    for f in range(frames):
        views = []
        for c, eye in enumerate(eyes):
            img = np.full((H, W, 3), 0.4, np.float32)
            img[2:6, 2 + 8 * f:6 + 8 * f] = 1.0
            views.append(View(_camera(c, eye, f, frames), None, loader=lambda img=img: img))
        by_frame[f / (frames - 1)] = views
    return by_frame


def test_medians_and_moving_pixels_find_the_walking_square():
    frames = _video()
    medians = camera_medians(frames)
    assert set(medians) == {("camera", 0), ("camera", 1)}
    assert np.allclose(medians[("camera", 0)], 0.4)  # the square is at each place in one frame of three
    first = next(iter(frames.values()))[0]
    moving = moving_pixels(first.image(), medians[("camera", 0)])
    assert moving[2:6, 2:6].all() and moving.sum() == 16
    # NaN in a frame counts as moving, never as still
    bad = first.image().copy()
    bad[10, 10, 1] = np.nan
    assert moving_pixels(bad, medians[("camera", 0)])[10, 10]


def test_points_on_still_pixels_are_still_and_the_rest_move():
    frames = _video()
    medians = camera_medians(frames)
    views = next(iter(frames.values()))  # frame 0
    cam0 = views[0].camera
    # the origin projects to the image centre of both cameras: grey in every frame
    # a point on camera 0's ray through the square's pixel (3.5, 3.5) at frame 0
    d = cam0.R.T @ np.array([(3.5 - cam0.cx) / cam0.fx, (3.5 - cam0.cy) / cam0.fy, 1.0])
    on_square = cam0.center + 3.0 * d / np.linalg.norm(d)
    outside_both = np.array([-40.0, -40.0, 0.0])  # in front of both cameras, outside both images
    points = np.stack([np.zeros(3), on_square, outside_both])
    moving = moving_point_mask(points, views, medians)
    assert moving.tolist() == [False, True, True]  # unseen counts as moving: nothing shows it still
    assert moving_point_mask(points[:1], views, {}).tolist() == [True]  # no medians: nothing is still


def test_4d_mvs_init_with_a_still_background_makes_time_constant_gaussians(monkeypatch):
    from gsgs_engine.train import dynamic
    from gsgs_engine.train.trainer import TrainConfig

    frames = _video()
    still_point = np.zeros((1, 3), np.float32)
    cam0 = frames[0.0][0].camera
    d = cam0.R.T @ np.array([(3.5 - cam0.cx) / cam0.fx, (3.5 - cam0.cy) / cam0.fy, 1.0])
    square = (cam0.center + 3.0 * d / np.linalg.norm(d)).astype(np.float32)[None]

    def fake_points(scene, views, seed=0, config=None, log=None):  # the plane sweep itself is tested elsewhere
        pts = np.concatenate([still_point, square if views[0].camera.time == 0.0 else still_point + 0.01])
        return pts, np.full_like(pts, 0.5), "mvs", ""

    monkeypatch.setattr("gsgs_engine.init.mvs.dense_and_sparse_points", fake_points)
    config = TrainConfig(init="mvs", sh_degree=0, static_background=True)
    model, info = dynamic._per_frame_mvs(None, frames, config, 0.5, log=lambda msg: None)
    tc = model.params["t_center"].detach().numpy()
    ts = model.t_scale.detach().numpy()
    # frame 0's square point stays at its frame; the still points are kept once, from the middle frame
    assert model.num_gaussians == 3
    assert tc[0] == pytest.approx(0.0) and ts[0] == pytest.approx(0.5)
    still = np.array([1, 2])
    assert np.allclose(tc[still], dynamic.STILL_T_CENTER) and np.allclose(ts[still], dynamic.STILL_T_SCALE)
    assert "start time-constant" in info.reason
    # the opacity of a still Gaussian hardly changes over the clip
    for t in (0.0, 0.5, 1.0):
        assert float(model.at_time(t)[3][1].detach() / model.at_time(0.5)[3][1].detach()) > 0.98
    # without the switch every point follows its frame, as before
    model, _ = dynamic._per_frame_mvs(None, frames, TrainConfig(init="mvs", sh_degree=0), 0.5, log=lambda m: None)
    assert model.num_gaussians == 6 and np.allclose(model.t_scale.detach().numpy(), 0.5)
