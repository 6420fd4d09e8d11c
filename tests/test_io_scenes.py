"""Scene loaders on the real shared scenes and on tiny scenes built here, including bad input."""

from __future__ import annotations

import json
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from gsgs_engine import GsgsError
from gsgs_engine.cameras import (Camera, colmap_from_camera, distort_normalized, llff_from_cameras, look_at,
                                 nerf_c2w_from_camera, undistort_normalized)
from gsgs_engine.io import detect_format, load_scene
from gsgs_engine.job import Job
from tests.conftest import shared_scene

LEGO_TRAIN = ["r_26", "r_86", "r_2", "r_55", "r_75", "r_93", "r_16", "r_73"]


# -- helpers ------------------------------------------------------------------------------------
def epipolar_error(a, b) -> tuple[int, float]:
    """(matches, median distance in px of SIFT matches in b to their epipolar lines from a's pose)."""
    gray = lambda v: cv2.cvtColor((v.image() * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY)  # noqa: E731
    sift = cv2.SIFT_create(nfeatures=1000)
    ka, da = sift.detectAndCompute(gray(a), None)
    kb, db = sift.detectAndCompute(gray(b), None)
    good = [m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < 0.7 * n.distance]
    pa = np.array([ka[m.queryIdx].pt for m in good]) + 0.5  # OpenCV pixel centres -> ours
    pb = np.array([kb[m.trainIdx].pt for m in good]) + 0.5
    A, B = a.camera, b.camera
    R = B.R @ A.R.T
    t = B.t - R @ A.t
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    F = np.linalg.inv(B.K).T @ tx @ R @ np.linalg.inv(A.K)
    lines = np.c_[pa, np.ones(len(pa))] @ F.T
    dist = np.abs(np.sum(lines * np.c_[pb, np.ones(len(pb))], axis=1)) / np.linalg.norm(lines[:, :2], axis=1)
    return len(good), float(np.median(dist))


def ring_cameras(n: int, width=32, height=24, radius=4.0) -> list[Camera]:
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        R, t = look_at([radius * np.cos(a), radius * np.sin(a), 1.0], [0, 0, 0])
        cams.append(Camera(R=R, t=t, fx=30, fy=30, cx=width / 2, cy=height / 2, width=width, height=height,
                           name=f"v{i:02d}"))
    return cams


def write_png(path: Path, width: int, height: int, channels: int = 3, value: int = 128) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.full((height, width, channels), value, np.uint8)
    if channels == 4:
        img[..., 3] = 255
        img[: height // 2, :, 3] = 0  # transparent top half
    assert cv2.imwrite(str(path), img)
    return path


def tiny_nerf(root: Path, n_train=3, n_test=2, sizes=None, rgba=True) -> Path:
    cams = ring_cameras(n_train + n_test)
    for split, idx in (("train", range(n_train)), ("test", range(n_train, n_train + n_test))):
        frames = []
        for i in idx:
            w, h = sizes[i] if sizes else (32, 24)
            write_png(root / split / f"r_{i}.png", w, h, 4 if rgba else 3)
            frames.append({"file_path": f"./{split}/r_{i}", "transform_matrix": nerf_c2w_from_camera(cams[i]).tolist()})
        (root / f"transforms_{split}.json").write_text(json.dumps({"camera_angle_x": cams[0].fov_x, "frames": frames}))
    return root


def tiny_llff(root: Path, n=10, n_images=None, sizes=None) -> Path:
    cams = ring_cameras(n, width=320, height=240)
    np.save(root / "poses_bounds.npy", llff_from_cameras(cams, near=1.0, far=8.0))
    for i in range(n if n_images is None else n_images):
        w, h = sizes[i] if sizes else (40, 30)
        write_png(root / "images_8" / f"img{i:03d}.png", w, h)
    return root


# -- real data: NeRF-synthetic lego ---------------------------------------------------------------
def test_lego_splits_names_cameras_and_alpha():
    scene = load_scene(shared_scene("lego_200"))
    assert scene.format == "blender" and scene.has_alpha
    assert {k: len(v) for k, v in scene.splits.items()} == {"train": 8, "test": 25, "dense": 67, "all_train": 8}
    assert [Path(v.image_path).stem for v in scene.train] == LEGO_TRAIN
    assert scene.train[0].name == "train/r_26"
    assert (scene.near, scene.far) == (2.0, 6.0)
    for view in scene.views:
        cam = view.camera
        assert (cam.width, cam.height) == (200, 200)
        assert cam.fx == pytest.approx(100 / np.tan(0.6911112070083618 / 2))
        uv, z = cam.project(np.zeros((1, 3)))  # every NeRF-synthetic camera looks at the origin
        np.testing.assert_allclose(uv[0], [100, 100], atol=0.01)
        assert 3.9 < z[0] < 4.2
    for view in scene.train:
        alpha = view.alpha()
        assert alpha.shape == (200, 200) and 0.05 < alpha.mean() < 0.8
        assert alpha[95:105, 95:105].mean() > 0.5  # the model covers the image centre


def test_lego_rgba_is_composited_on_the_background():
    path = shared_scene("lego_200")
    white = load_scene(path).train[0]
    black = load_scene(path, background=(0, 0, 0)).train[0]
    img_w, img_b, alpha = white.image(), black.image(), white.alpha()
    assert img_w.dtype == np.float32 and img_w.shape == (200, 200, 3)
    np.testing.assert_allclose(img_w - img_b, np.repeat((1 - alpha)[..., None], 3, axis=2), atol=1e-6)


def test_lego_poses_agree_with_the_pixels():
    # SIFT matches between the two closest views must lie on the epipolar lines of their poses:
    # a wrong axis convention (flipped y/z, transposed rotation) puts them pixels away.
    scene = load_scene(shared_scene("lego_200"), train_split="train+dense")
    centers = np.stack([v.camera.center for v in scene.train])
    d = np.linalg.norm(centers[:, None] - centers[None], axis=-1) + 1e9 * np.eye(len(centers))
    i, j = np.unravel_index(np.argmin(d), d.shape)
    matches, err = epipolar_error(scene.train[i], scene.train[j])
    assert matches > 50 and err < 0.5


def test_lego_train_split_and_train_selection():
    path = shared_scene("lego_200")
    dense = load_scene(path, train_split="dense")
    assert len(dense.train) == 67 and len(dense.test) == 25
    assert [Path(dense.views[i].image_path).stem for i in dense.splits["transforms_train"]] == LEGO_TRAIN
    both = load_scene(path, train_split="train+dense")
    assert len(both.train) == 75 and len(set(both.splits["train"])) == 75
    by_name = load_scene(path, train_ids=["r_55", "train/r_2", "r_26.png"])
    assert [Path(v.image_path).stem for v in by_name.train] == ["r_55", "r_2", "r_26"]
    assert [Path(v.image_path).stem for v in load_scene(path, train_ids=["1", "3"]).train] == ["r_86", "r_55"]
    by_pos = load_scene(path, train_ids=[0, 7])
    assert [Path(v.image_path).stem for v in by_pos.train] == ["r_26", "r_73"]
    assert len(by_pos.splits["all_train"]) == 8 and len(by_pos.test) == 25
    spread = load_scene(path, train_views=3)
    assert [Path(v.image_path).stem for v in spread.train] == ["r_26", "r_75", "r_73"]  # positions 0, 4, 7
    with pytest.raises(GsgsError, match="transforms_val.json"):
        load_scene(path, train_split="val")
    with pytest.raises(GsgsError, match="out of range"):
        load_scene(path, train_ids=[8])
    with pytest.raises(GsgsError, match="r_999"):
        load_scene(path, train_ids=["r_999"])
    with pytest.raises(GsgsError, match="at most 8"):
        load_scene(path, train_views=9)
    with pytest.raises(GsgsError, match="either"):
        load_scene(path, train_ids=[0], train_views=2)


def test_lego_resolution_scale():
    scene = load_scene(shared_scene("lego_200"), resolution_scale=0.5)
    view = scene.train[0]
    assert (view.camera.width, view.camera.height) == (100, 100)
    assert view.camera.fx == pytest.approx(50 / np.tan(0.6911112070083618 / 2))
    assert view.image().shape == (100, 100, 3) and view.alpha().shape == (100, 100)


def test_max_side_caps_the_longer_side_after_the_scale(tmp_path):
    root = tiny_nerf(tmp_path, sizes=[(64, 48)] * 5)
    scene = load_scene(root, max_side=32)  # 64x48 -> 32x24: the scale that brings the longer side to 32
    assert scene.resolution_scale == pytest.approx(0.5)
    for view in scene.views:
        assert (view.camera.width, view.camera.height) == (32, 24)
    assert scene.train[0].image().shape == (24, 32, 3)
    same = load_scene(root, resolution_scale=0.5)
    assert same.train[0].camera.fx == pytest.approx(scene.train[0].camera.fx)
    capped = load_scene(root, resolution_scale=0.75, max_side=24)  # 48x36 after the scale, then 24x18
    assert capped.resolution_scale == pytest.approx(0.375) and capped.test[0].camera.width == 24
    for cap in (None, 0, 64, 1000):  # no cap, or one the views are within: loaded as they are
        scene = load_scene(root, max_side=cap)
        assert scene.resolution_scale == 1.0 and scene.train[0].camera.width == 64


def test_loading_decodes_no_image(monkeypatch):
    calls = []
    real = cv2.imread
    monkeypatch.setattr(cv2, "imread", lambda *a, **k: calls.append(a[0]) or real(*a, **k))
    scene = load_scene(shared_scene("lego_200"))
    llff = load_scene(shared_scene("llff_flower"), train_views=3)
    assert calls == []
    scene.train[0].image()
    llff.test[0].image()
    assert len(calls) == 2 and calls[0].endswith("r_26.png")


# -- real data: LLFF flower --------------------------------------------------------------------
def test_llff_flower_splits_and_cameras():
    path = shared_scene("llff_flower")
    scene = load_scene(path, train_views=3)
    assert scene.format == "llff" and not scene.has_alpha
    assert scene.splits["test"] == [0, 8, 16, 24, 32]
    assert len(scene.splits["all_train"]) == 29 and not set(scene.splits["all_train"]) & set(scene.splits["test"])
    # round(linspace(0, 28, 3)) = positions 0, 14, 28 of the non-test images
    assert [v.name for v in scene.train] == ["image001", "image017", "image033"]
    bounds = np.load(path / "poses_bounds.npy")[:, 15:]
    assert (scene.near, scene.far) == (bounds.min(), bounds.max())
    hwf = np.load(path / "poses_bounds.npy")[0, :15].reshape(3, 5)[:, 4]
    cam = scene.views[0].camera
    assert (cam.width, cam.height) == (504, 378)
    assert cam.fx == pytest.approx(hwf[2] * 504 / hwf[1]) and (cam.cx, cam.cy) == (252, 189)
    assert scene.train[0].image().shape == (378, 504, 3)
    # forward-facing capture: a point ahead of the rig, between the near bounds, is in every photo
    centers = np.stack([v.camera.center for v in scene.views])
    forward = np.stack([v.camera.R[2] for v in scene.views]).mean(axis=0)
    point = centers.mean(axis=0) + forward / np.linalg.norm(forward) * 2 * np.median(bounds[:, 0])
    for view in scene.views:
        uv, z = view.camera.project(point[None])
        assert z[0] > 0 and 0 < uv[0, 0] < 504 and 0 < uv[0, 1] < 378, view.name
    matches, err = epipolar_error(scene.views[1], scene.views[2])
    assert matches > 100 and err < 0.5


def test_llff_all_non_test_views_by_default_and_colmap_twin(tmp_path):
    """The flower poses written as a COLMAP text model load to the same cameras."""
    src = shared_scene("llff_flower")
    llff = load_scene(src)
    assert llff.splits["train"] == llff.splits["all_train"]
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    (tmp_path / "images").mkdir()
    cams, imgs = [], []
    for i, view in enumerate(llff.views, start=1):
        q, t, name, params = colmap_from_camera(view.camera)
        cams.append(f"{i} {name} {view.camera.width} {view.camera.height} " + " ".join(map(repr, params)))
        imgs.append(f"{i} " + " ".join(map(repr, [*q, *t])) + f" {i} {view.image_path.name}\n")
        os.symlink(view.image_path, tmp_path / "images" / view.image_path.name)
    (model / "cameras.txt").write_text("\n".join(cams) + "\n")
    (model / "images.txt").write_text("\n".join(imgs) + "\n")
    (model / "points3D.txt").write_text("1 0.5 -1.0 30.0 255 128 0 0.1\n2 1.0 2.0 40.0 0 0 255 0.2\n")
    assert detect_format(tmp_path) == "colmap"
    colmap = load_scene(tmp_path, train_views=3)
    assert colmap.splits["test"] == llff.splits["test"]
    assert [v.name for v in colmap.train] == ["image001", "image017", "image033"]
    for a, b in zip(llff.views, colmap.views):
        assert a.name == b.name
        np.testing.assert_allclose(a.camera.world_to_camera, b.camera.world_to_camera, atol=1e-9)
        np.testing.assert_allclose(a.camera.K, b.camera.K, atol=1e-9)
    np.testing.assert_allclose(colmap.points, [[0.5, -1.0, 30.0], [1.0, 2.0, 40.0]], atol=1e-6)
    np.testing.assert_allclose(colmap.point_colors, [[1.0, 128 / 255, 0], [0, 0, 1.0]], atol=1e-6)


# -- COLMAP with a distorted camera ------------------------------------------------------------
def test_colmap_distorted_photo_is_undistorted_on_load(tmp_path):
    # The photo shows a smooth pattern defined on undistorted normalized coordinates, seen through
    # an OPENCV camera. After loading, the pinhole view must show the same pattern undistorted.
    width, height = 160, 120
    fx, fy, cx, cy = 150.0, 148.0, 81.0, 59.0
    coeffs = {"k1": -0.15, "k2": 0.03, "p1": 0.001, "p2": -0.0015}
    pattern = lambda x, y: 0.5 + 0.4 * np.sin(4 * x + 1) * np.cos(3 * y)  # noqa: E731
    v, u = np.meshgrid(np.arange(height) + 0.5, np.arange(width) + 0.5, indexing="ij")
    x, y = undistort_normalized((u - cx) / fx, (v - cy) / fy, coeffs)
    xd, yd = distort_normalized(x, y, coeffs)
    assert np.abs(xd - (u - cx) / fx).max() < 1e-9
    photo = np.round(np.repeat(pattern(x, y)[..., None], 3, axis=2) * 65535).astype(np.uint16)
    (tmp_path / "images").mkdir()
    cv2.imwrite(str(tmp_path / "images" / "a.png"), photo)
    model = tmp_path / "sparse" / "0"
    model.mkdir(parents=True)
    (model / "cameras.txt").write_text(f"1 OPENCV {width} {height} {fx} {fy} {cx} {cy} "
                                       f"{coeffs['k1']} {coeffs['k2']} {coeffs['p1']} {coeffs['p2']}\n")
    (model / "images.txt").write_text("1 1 0 0 0 0 0 0 1 a.png\n\n")
    (model / "points3D.txt").write_text("")
    scene = load_scene(tmp_path, format="colmap")
    assert scene.points is None
    view = scene.views[0]
    cam = view.camera
    assert (cam.width, cam.height) == (width, height)
    img = view.image()
    expected = pattern((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy)
    err = np.abs(img[..., 0] - expected)
    assert np.median(err) < 5e-4 and err[2:-2, 2:-2].max() < 3e-3  # bilinear resampling error only (measured 5e-5, 2e-4)
    # the same photo read without undistortion is measurably different
    raw = np.abs(photo[..., 0] / 65535.0 - expected)
    assert np.median(raw) > 5 * np.median(err)


# -- job folders ---------------------------------------------------------------------------------
def test_job_folder_naming_a_scene(tmp_path):
    lego = shared_scene("lego_200")
    Job.create(tmp_path / "job", "train", data={"source": str(lego), "format": "blender", "train_ids": [0, 1, 2]})
    assert detect_format(tmp_path / "job") == "job"
    scene = load_scene(tmp_path / "job")
    assert [Path(v.image_path).stem for v in scene.train] == LEGO_TRAIN[:3] and len(scene.test) == 25
    assert len(load_scene(tmp_path / "job", train_ids=[5]).train) == 1  # arguments win over job.json


def test_job_folder_with_inline_cameras(tmp_path):
    cams = ring_cameras(4)
    job_dir = tmp_path / "job"
    entries = []
    for i, cam in enumerate(cams):
        write_png(job_dir / "images" / f"{cam.name}.png", 32, 24, channels=4)
        entries.append({**cam.to_dict(), "image": f"images/{cam.name}.png", "split": "test" if i == 3 else "train"})
    Job.create(job_dir, "train", data={"cameras": entries, "background": [0, 0, 0]})
    scene = load_scene(job_dir)
    assert scene.format == "job" and scene.has_alpha
    assert scene.splits["train"] == [0, 1, 2] and scene.splits["test"] == [3]
    np.testing.assert_allclose(scene.views[2].camera.world_to_camera, cams[2].world_to_camera)
    img = scene.train[0].image()
    assert img[0, 0].tolist() == [0, 0, 0]  # transparent pixel on the job's black background
    assert img[-1, -1] == pytest.approx(np.full(3, 128 / 255))
    assert len(load_scene(job_dir, train_views=2).train) == 2
    assert scene.points is None
    from gsgs_engine.io.ply import write_ply_vertices

    pts = np.array([[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]], np.float32)
    rgb = np.array([[255, 0, 0], [0, 255, 0]], np.uint8)
    write_ply_vertices(job_dir / "points.ply", {"x": pts[:, 0], "y": pts[:, 1], "z": pts[:, 2],
                                                "red": rgb[:, 0], "green": rgb[:, 1], "blue": rgb[:, 2]})
    Job.create(job_dir, "train", data={"cameras": entries, "points": "points.ply"})
    with_points = load_scene(job_dir)
    np.testing.assert_array_equal(with_points.points, pts)
    np.testing.assert_allclose(with_points.point_colors, [[1, 0, 0], [0, 1, 0]])
    entries[1]["image"] = "images/missing.png"
    Job.create(job_dir, "train", data={"cameras": entries})
    with pytest.raises(GsgsError, match="missing.png.*missing"):
        load_scene(job_dir)
    Job.create(job_dir, "train", data={})
    with pytest.raises(GsgsError, match="names no scene"):
        load_scene(job_dir)


# -- format detection and bad input ---------------------------------------------------------------
def test_detect_format(tmp_path):
    assert detect_format(tiny_nerf(tmp_path / "nerf")) == "blender"
    assert detect_format(tmp_path / "nerf" / "transforms_train.json") == "blender"
    llff = tmp_path / "llff"
    llff.mkdir()
    assert detect_format(tiny_llff(llff)) == "llff"
    write_png(tmp_path / "photos" / "a.jpg", 8, 8)
    assert detect_format(tmp_path / "photos") == "photos"
    (tmp_path / "empty").mkdir()
    with pytest.raises(GsgsError, match="unknown scene format.*transforms_.*poses_bounds.*sparse/0"):
        detect_format(tmp_path / "empty")
    with pytest.raises(GsgsError, match="no such file"):
        load_scene(tmp_path / "nowhere")
    with pytest.raises(GsgsError, match="format"):
        load_scene(tmp_path / "nerf", format="mesh")


def test_tiny_nerf_loads_with_size_from_png_header(tmp_path):
    scene = load_scene(tiny_nerf(tmp_path))
    assert len(scene.train) == 3 and len(scene.test) == 2 and scene.has_alpha
    assert scene.train[0].camera.width == 32 and scene.train[0].image().shape == (24, 32, 3)
    assert not load_scene(tiny_nerf(tmp_path / "rgb", rgba=False)).has_alpha
    # instant-ngp style: per-file fl_x / w / h describing photos twice the size on disk
    meta = json.loads((tmp_path / "transforms_train.json").read_text())
    del meta["camera_angle_x"]
    meta.update(fl_x=60.0, fl_y=62.0, cx=33.0, cy=24.0, w=64, h=48)
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    cam = load_scene(tmp_path).train[0].camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (30.0, 31.0, 16.5, 12.0, 32, 24)
    meta["k1"] = -0.1  # OPENCV distortion keys: the view is resampled to a pinhole camera
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    view = load_scene(tmp_path).train[0]
    assert view.loader.undistortion is not None and view.camera.fx < 30.0
    assert view.image().shape == (24, 32, 3)
    meta["camera_model"] = "OPENCV_FISHEYE"
    (tmp_path / "transforms_train.json").write_text(json.dumps(meta))
    with pytest.raises(GsgsError, match="camera_model OPENCV_FISHEYE is not supported"):
        load_scene(tmp_path)


def test_photos_folder_says_run_sfm(tmp_path):
    write_png(tmp_path / "a.jpg", 8, 8)
    write_png(tmp_path / "b.jpg", 8, 8)
    with pytest.raises(GsgsError, match=r"2 photos without camera poses; run `gsgs sfm .* --out DIR` first"):
        load_scene(tmp_path)


def test_missing_and_unreadable_images(tmp_path):
    root = tiny_nerf(tmp_path)
    (root / "train" / "r_1.png").unlink()
    with pytest.raises(GsgsError, match=r"train/r_1: image file is missing .*transforms_train.json frame 1"):
        load_scene(root)
    (root / "train" / "r_1.png").write_bytes(b"not an image at all")
    with pytest.raises(GsgsError, match="r_1.png: OpenCV cannot decode"):
        load_scene(root)


def test_image_removed_after_loading_fails_clearly(tmp_path):
    scene = load_scene(tiny_nerf(tmp_path))
    Path(scene.train[0].image_path).unlink()
    with pytest.raises(GsgsError, match="r_0.png: image file is missing"):
        scene.train[0].image()


def test_nan_pose_is_refused(tmp_path):
    root = tiny_nerf(tmp_path / "nerf")
    meta = json.loads((root / "transforms_test.json").read_text())
    meta["frames"][1]["transform_matrix"][0][3] = float("nan")
    (root / "transforms_test.json").write_text(json.dumps(meta))
    with pytest.raises(GsgsError, match="transforms_test.json frame 1.*NaN"):
        load_scene(root)
    llff = tmp_path / "llff"
    llff.mkdir()
    tiny_llff(llff)
    arr = np.load(llff / "poses_bounds.npy")
    arr[4, 7] = np.inf
    np.save(llff / "poses_bounds.npy", arr)
    with pytest.raises(GsgsError, match=r"poses_bounds.npy row 4 \(img004\).*NaN or Inf"):
        load_scene(llff)


def test_llff_count_mismatch(tmp_path):
    tiny_llff(tmp_path, n=10, n_images=9)
    with pytest.raises(GsgsError, match="10 poses but 9 images in .*images_8"):
        load_scene(tmp_path)


def test_mixed_image_sizes_in_a_split(tmp_path):
    sizes = [(32, 24), (32, 24), (30, 24), (32, 24), (32, 24)]
    with pytest.raises(GsgsError, match=r"r_2.png: image is 30x24 but r_0.png in the same split 'train'"):
        load_scene(tiny_nerf(tmp_path / "nerf", sizes=sizes))
    llff = tmp_path / "llff"
    llff.mkdir()
    with pytest.raises(GsgsError, match="img003.png: image is 40x32"):
        load_scene(tiny_llff(llff, sizes=[(40, 30)] * 3 + [(40, 32)] + [(40, 30)] * 6))


def test_malformed_json(tmp_path):
    root = tiny_nerf(tmp_path)
    (root / "transforms_train.json").write_text('{"camera_angle_x": 0.7, "frames": [')
    with pytest.raises(GsgsError, match="transforms_train.json: not valid JSON"):
        load_scene(root)
    (root / "transforms_train.json").write_text('{"camera_angle_x": 0.7}')
    with pytest.raises(GsgsError, match="frames"):
        load_scene(root)


def test_bad_arguments(tmp_path):
    root = tiny_nerf(tmp_path)
    with pytest.raises(GsgsError, match="resolution_scale"):
        load_scene(root, resolution_scale=0)
    with pytest.raises(GsgsError, match="background"):
        load_scene(root, background=(0, 0, 2))
