"""Multi-view video loaders: Neural-3D-Video (videos and frame folders) and NeRF JSON with time;
the camera-0-held-out protocol, time normalisation, lazy decoding and clear errors."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera, llff_from_cameras, look_at, nerf_c2w_from_camera
from gsgs_engine.io.dynamic import (VideoFrameLoader, apply_camera_protocol, camera_index, has_time, is_n3dv,
                                    load_dynamic_scene)
from gsgs_engine.io.loader import load_scene


def ring_cameras(n: int, size: int = 16) -> list[Camera]:
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        R, t = look_at((4 * np.cos(a), 4 * np.sin(a), 1.5), (0, 0, 0))
        cams.append(Camera(R=R, t=t, fx=20.0, fy=20.0, cx=size / 2, cy=size / 2, width=size, height=size,
                           name=f"cam{i:02d}"))
    return cams


def frame_image(cam: int, frame: int, size: int = 16) -> np.ndarray:
    """A recognisable uint8 BGR image per (camera, frame): value encodes both."""
    img = np.zeros((size, size, 3), np.uint8)
    img[..., 0] = 20 * cam
    img[..., 1] = 20 * frame
    img[..., 2] = 128
    return img


def write_nerf_with_time(root, n_cams=4, n_frames=3, size=16, times=None, key="camera_id", drop_time_at=None):
    root.mkdir(parents=True, exist_ok=True)
    (root / "frames").mkdir(exist_ok=True)
    times = list(np.linspace(0, 1, n_frames)) if times is None else times
    frames = []
    for f in range(n_frames):
        for c, cam in enumerate(ring_cameras(n_cams, size)):
            stem = f"frames/c{c}_f{f}"
            cv2.imwrite(str(root / f"{stem}.png"), frame_image(c, f, size))
            entry = {"file_path": f"./{stem}", "transform_matrix": nerf_c2w_from_camera(cam).tolist(),
                     "time": float(times[f])}
            if key == "camera_id":
                entry["camera_id"] = c
            elif key == "camera_name":
                entry["camera_name"] = f"cam{c:02d}"
            frames.append(entry)
    if drop_time_at is not None:
        del frames[drop_time_at]["time"]
    meta = {"fl_x": 20.0, "fl_y": 20.0, "cx": size / 2, "cy": size / 2, "w": size, "h": size, "frames": frames}
    (root / "transforms.json").write_text(json.dumps(meta))
    return root


def write_n3dv(root, n_cams=5, n_frames=4, size=16, videos=True):
    root.mkdir(parents=True, exist_ok=True)
    cams = ring_cameras(n_cams, size)
    np.save(root / "poses_bounds.npy", llff_from_cameras(cams, near=1.0, far=8.0))
    for c in range(n_cams):
        if videos:
            writer = cv2.VideoWriter(str(root / f"cam{c:02d}.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (size, size))
            assert writer.isOpened()
            for f in range(n_frames):
                writer.write(frame_image(c, f, size))
            writer.release()
        else:
            folder = root / f"cam{c:02d}" / "images"
            folder.mkdir(parents=True)
            for f in range(n_frames):
                cv2.imwrite(str(folder / f"{f:04d}.png"), frame_image(c, f, size))
    return root


def test_nerf_with_time_protocol_and_normalised_time(tmp_path):
    root = write_nerf_with_time(tmp_path / "d", n_cams=7, n_frames=3, times=[10.0, 15.0, 20.0])
    assert has_time(root) and not is_n3dv(root)
    scene = load_dynamic_scene(root, train_cameras=3)
    assert scene.has_time and len(scene.views) == 21
    assert sorted({v.time for v in scene.views}) == [0.0, 0.5, 1.0]
    assert {camera_index(v) for v in scene.test} == {0} and len(scene.test) == 3
    # 3 of cameras 1..6, evenly: positions round(linspace(0, 5, 3)) = 0, 2(.5->2), 5 -> cameras 1, 3, 6
    assert sorted({camera_index(v) for v in scene.train}) == [1, 3, 6]
    assert sorted({camera_index(v) for v in scene.split("all_train")}) == [1, 2, 3, 4, 5, 6]
    v = scene.test[1]
    assert v.camera.extra["frame"] == 1
    assert np.allclose(v.image()[0, 0], np.array([128, 20, 0]) / 255.0, atol=1 / 255)  # camera 0, frame 1


@pytest.mark.parametrize("key", ["camera_name", "pose"])
def test_cameras_grouped_by_name_or_identical_pose(tmp_path, key):
    scene = load_dynamic_scene(write_nerf_with_time(tmp_path / "d", n_cams=4, key=key), train_cameras=1)
    assert len({camera_index(v) for v in scene.views}) == 4
    assert len(scene.train) == 3 and len(scene.test) == 3


def test_max_frames_keeps_first_and_last(tmp_path):
    scene = load_dynamic_scene(write_nerf_with_time(tmp_path / "d", n_cams=3, n_frames=5), max_frames=3)
    assert sorted({v.time for v in scene.views}) == [0.0, 0.5, 1.0]
    assert len(scene.views) == 9 and len(scene.test) == 3


def test_monocular_dnerf_keeps_file_splits(tmp_path):
    root = tmp_path / "dnerf"
    root.mkdir()
    cams = ring_cameras(6)
    for split, ids in (("train", [0, 1, 2, 3]), ("test", [4, 5])):
        (root / split).mkdir()
        frames = []
        for k, i in enumerate(ids):
            cv2.imwrite(str(root / split / f"r_{k}.png"), frame_image(i, i))
            frames.append({"file_path": f"./{split}/r_{k}", "transform_matrix": nerf_c2w_from_camera(cams[i]).tolist(),
                           "time": i / 5})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": 0.8, "frames": frames}))
    scene = load_dynamic_scene(root)
    assert len(scene.train) == 4 and len(scene.test) == 2 and scene.test[1].time == 1.0
    with pytest.raises(GsgsError, match="monocular"):
        load_dynamic_scene(root, train_cameras=2)


def test_time_on_some_frames_only_is_an_error(tmp_path):
    root = write_nerf_with_time(tmp_path / "d", drop_time_at=4)
    with pytest.raises(GsgsError, match=r"transforms.json frame 4: no \"time\""):
        load_dynamic_scene(root)


def test_static_nerf_folder_has_no_time(tmp_path):
    root = write_nerf_with_time(tmp_path / "d")
    meta = json.loads((root / "transforms.json").read_text())
    for fr in meta["frames"]:
        del fr["time"]
    (root / "transforms.json").write_text(json.dumps(meta))
    assert not has_time(root)
    assert not load_scene(root).has_time


@pytest.mark.parametrize("videos", [True, False])
def test_n3dv_videos_and_frame_folders(tmp_path, videos):
    root = write_n3dv(tmp_path / "n3dv", n_cams=5, n_frames=4, videos=videos)
    assert is_n3dv(root) and has_time(root)
    scene = load_dynamic_scene(root, train_cameras=2)
    assert scene.format == "n3dv" and len(scene.views) == 20
    assert sorted({v.time for v in scene.views}) == pytest.approx([0.0, 1 / 3, 2 / 3, 1.0])
    assert sorted({camera_index(v) for v in scene.train}) == [1, 4]
    assert {camera_index(v) for v in scene.test} == {0}
    view = next(v for v in scene.views if camera_index(v) == 3 and v.camera.extra["frame"] == 2)
    if videos:
        assert isinstance(view.loader, VideoFrameLoader) and view.loader.index == 2
    img = view.image()
    assert img.shape == (16, 16, 3)
    # MJPG is lossy: compare the frame's encoded colour loosely (B=60, G=40, R=128 -> RGB)
    assert np.allclose(img.mean(axis=(0, 1)), np.array([128, 40, 60]) / 255.0, atol=0.04)
    # the poses survive the LLFF round trip
    cam = ring_cameras(5)[3]
    assert np.allclose(view.camera.center, cam.center, atol=1e-6)


def test_n3dv_resolution_scale_and_errors(tmp_path):
    root = write_n3dv(tmp_path / "n3dv", n_cams=3, n_frames=2, videos=False)
    scene = load_dynamic_scene(root, resolution_scale=0.5)
    assert scene.views[0].image().shape == (8, 8, 3) and scene.views[0].camera.fx == pytest.approx(10.0)
    with pytest.raises(GsgsError, match="at most 2"):
        load_dynamic_scene(root, train_cameras=3)
    with pytest.raises(GsgsError, match="no camera 7"):
        apply_camera_protocol(scene, test_camera=7)
    np.save(root / "poses_bounds.npy", np.load(root / "poses_bounds.npy")[:2])
    with pytest.raises(GsgsError, match="2 poses but 3 cameras"):
        load_dynamic_scene(root)


def test_video_loader_reports_a_missing_frame(tmp_path):
    root = write_n3dv(tmp_path / "n3dv", n_cams=2, n_frames=2)
    with pytest.raises(GsgsError, match="cannot decode frame 9"):
        VideoFrameLoader(root / "cam00.avi", 9, (16, 16))()


@pytest.mark.slow
def test_blender_dynamic_scene_renders_a_loadable_clip(tmp_path):
    """Real bpy + Cycles (16 px, 3 cameras x 2 frames): files, times, camera grouping, motion between frames."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    pytest.importorskip("bpy", reason="the bpy module is not installed (pip install bpy)")
    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(repo)}
    proc = subprocess.run([sys.executable, "-m", "gsgs_blender.dynamic_scene", str(tmp_path / "clip"), "--cameras", "3",
                           "--frames", "2", "--size", "16", "--samples", "1"], env=env, cwd=repo,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    scene = load_dynamic_scene(tmp_path / "clip", train_cameras=2)
    assert scene.has_alpha and len(scene.views) == 6
    assert sorted({v.time for v in scene.views}) == [0.0, 1.0]
    assert {camera_index(v) for v in scene.test} == {0} and len(scene.train) == 4
    first, last = (v.image() for v in scene.test)
    assert np.abs(first - last).max() > 0.1  # the objects moved between the two frames
    cams = [v.camera for v in scene.views if v.camera.extra["frame"] == 0]
    # the ring looks at the scene: the target (0, 0, 0.35) projects near every image centre
    for cam in cams:
        uv, z = cam.project(np.array([[0.0, 0.0, 0.35]]))
        assert z[0] > 0 and np.allclose(uv[0], [8.0, 8.0], atol=0.5)


def test_load_scene_routes_time_data_to_the_camera_protocol(tmp_path):
    write_nerf_with_time(tmp_path / "nerf", n_cams=5, n_frames=3)
    scene = load_scene(tmp_path / "nerf", train_views=2)
    assert scene.has_time
    train_cams = {camera_index(v) for v in scene.train}
    assert len(train_cams) == 2 and 0 not in train_cams
    assert {camera_index(v) for v in scene.test} == {0}
    write_n3dv(tmp_path / "n3dv", n_cams=5, n_frames=3)
    from gsgs_engine.io.loader import detect_format

    assert detect_format(tmp_path / "n3dv") == "n3dv"
    assert load_scene(tmp_path / "n3dv", train_views=3).has_time
    with pytest.raises(GsgsError, match="--train-views"):
        load_scene(tmp_path / "nerf", train_ids=[1])
