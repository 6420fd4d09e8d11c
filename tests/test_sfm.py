"""Structure from motion (gsgs_engine.sfm): real pycolmap runs on the shared photos and renders."""

from __future__ import annotations

import json
import logging
import struct
import subprocess
import sys
from pathlib import Path

import zlib  # noqa: F401  -- before anything loads pycolmap (see gsgs_engine.sfm's docstring)

import numpy as np
import pytest

from conftest import REPO, shared_scene
from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.cli import main
from gsgs_engine.job import Job
from gsgs_engine.sfm import (run_sfm, run_sfm_job, triangulate_known_poses,
                             triangulate_with_known_poses, write_point_ply)


def _write_image(path: Path, img: np.ndarray) -> None:
    import cv2

    assert cv2.imwrite(str(path), img)


def _blank_folder(root: Path, n: int = 2) -> Path:
    root.mkdir()
    for i in range(n):
        _write_image(root / f"blank_{i}.png", np.full((240, 320, 3), 128, np.uint8))
    return root


def _read_point_ply(path: Path) -> np.ndarray:
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode()
    count = int(header.split("element vertex ")[1].split()[0])
    dtype = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]
    return np.frombuffer(data[end:], dtype=dtype, count=count)


def _read_colmap_cameras_bin(path: Path) -> list[tuple[int, int, int, tuple]]:
    """Classic COLMAP cameras.bin, parsed by hand: loaders without pycolmap read it this way."""
    data = path.read_bytes()
    (n,), off = struct.unpack_from("<Q", data), 8
    cams = []
    for _ in range(n):
        cam_id, model, w, h = struct.unpack_from("<iiQQ", data, off)
        off += 24
        nparams = {0: 3, 1: 4, 2: 4}[model]  # SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL
        params = struct.unpack_from(f"<{nparams}d", data, off)
        off += 8 * nparams
        cams.append((model, w, h, params))
    return cams


# -- input validation (no pycolmap needed) ---------------------------------------------------
def test_unreadable_image_is_a_clear_error_naming_the_file(tmp_path, capsys):
    photos = tmp_path / "photos"
    photos.mkdir()
    _write_image(photos / "good.png", np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8))
    (photos / "notes.txt").write_text("not a photo")
    (photos / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe0 this is not really a jpeg")
    with pytest.raises(GsgsError, match=r"broken\.jpg: cannot be read as an image"):
        run_sfm(photos, tmp_path / "out")
    # The command line turns it into one line and exit status 2, no traceback.
    assert main(["sfm", str(photos), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "broken.jpg" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_non_image_files_are_skipped_and_one_photo_is_not_enough(tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "readme.md").write_text("# my photos")
    _write_image(photos / "only.png", np.zeros((32, 32, 3), np.uint8))
    with pytest.raises(GsgsError, match=r"found 1 image\(s\); structure from motion needs at least 2"):
        run_sfm(photos, tmp_path / "out")
    with pytest.raises(GsgsError, match="not a folder"):
        run_sfm(tmp_path / "missing", tmp_path / "out")
    with pytest.raises(GsgsError, match="camera model 'BROWN'"):
        run_sfm(photos, tmp_path / "out", camera_model="BROWN")


def test_output_folder_never_overwrites_photos_or_foreign_files(tmp_path):
    scene = tmp_path / "scene"
    (scene / "images").mkdir(parents=True)
    for i in range(2):
        _write_image(scene / "images" / f"{i}.png", np.zeros((32, 32, 3), np.uint8))
    with pytest.raises(GsgsError, match="would overwrite the photos"):
        run_sfm(scene / "images", scene)
    foreign = tmp_path / "foreign"
    (foreign / "sparse").mkdir(parents=True)
    with pytest.raises(GsgsError, match="not written by gsgs sfm"):
        run_sfm(scene / "images", foreign)
    assert (foreign / "sparse").is_dir() and len(list((scene / "images").iterdir())) == 2


def test_point_ply_is_plain_xyz_rgb(tmp_path):
    pts = np.array([[0.0, 1.0, 2.0], [-1.5, 0.25, 3.0]], np.float32)
    cols = np.array([[1.0, 0.0, 0.5], [0.2, 0.4, 1.0]], np.float32)
    write_point_ply(tmp_path / "p.ply", pts, cols)
    v = _read_point_ply(tmp_path / "p.ply")
    np.testing.assert_array_equal(np.stack([v["x"], v["y"], v["z"]], 1), pts)
    np.testing.assert_array_equal(np.stack([v["red"], v["green"], v["blue"]], 1), [[255, 0, 128], [51, 102, 255]])


# -- pycolmap runs ---------------------------------------------------------------------------
def test_identical_blank_images_give_a_report_not_a_crash(tmp_path, capsys):
    photos = _blank_folder(tmp_path / "blank")
    out = tmp_path / "out"
    # run_sfm raises SfmFailed; the command prints the per-view story from it and exits 1
    # (a result, not a usage error).
    assert main(["sfm", str(photos), "--out", str(out)]) == 1
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert "registered 0/2 views" in lines
    assert any(line.strip().startswith("blank_0.png: no features") for line in lines)
    assert "no reconstruction could be built" in captured.err and "more overlap" in captured.err
    assert "strategies tried: incremental 4deg, incremental 2deg, incremental 1deg, incremental 0.5deg, global" \
        in captured.err
    report = json.loads((out / "sfm_report.json").read_text())
    assert report["registered"] == 0 and report["total"] == 2 and report["models"] == []
    assert [v["reason"].split(":")[0] for v in report["views"]] == ["no features", "no features"]


def test_cancel_request_stops_the_sfm_job(tmp_path):
    job = Job.create(tmp_path / "job", "sfm", data={"photos": str(_blank_folder(tmp_path / "photos"))})
    job.request_cancel()
    with pytest.raises(KeyboardInterrupt):
        run_sfm_job(job)
    assert not (job.result_dir / "cameras.json").exists()


def test_triangulation_of_blank_views_returns_empty_arrays(caplog):
    cam = Camera(R=np.eye(3), t=np.zeros(3), fx=100, fy=100, cx=32, cy=32, width=64, height=64)
    cam2 = cam.with_pose(np.eye(3), np.array([-0.5, 0.0, 0.0]))
    blank = np.full((64, 64, 3), 0.5, np.float32)
    with caplog.at_level(logging.WARNING, logger="gsgs_engine.sfm"):
        points, colors = triangulate_known_poses([(cam, blank), (cam2, blank)])
    assert points.shape == (0, 3) and colors.shape == (0, 3)
    assert "fewer than 2 views have features" in caplog.text


def test_triangulation_of_tiny_images_is_skipped_with_the_reason(caplog):
    """pycolmap's SIFT crashes its process on 16x12 px images: such views give no points and say why."""
    rng = np.random.default_rng(0)
    cam = Camera(R=np.eye(3), t=np.zeros(3), fx=16, fy=16, cx=8, cy=6, width=16, height=12)
    cam2 = cam.with_pose(np.eye(3), np.array([-0.5, 0.0, 0.0]))
    with caplog.at_level(logging.WARNING, logger="gsgs_engine.sfm"):
        points, colors = triangulate_known_poses([(cam, rng.random((12, 16, 3), dtype=np.float32)),
                                                  (cam2, rng.random((12, 16, 3), dtype=np.float32))])
    assert points.shape == (0, 3) and colors.shape == (0, 3)
    assert "too small for SIFT features" in caplog.text


@pytest.mark.slow
def test_santorini_registers_all_three_photos_via_the_command(tmp_path):
    photos = shared_scene("photos_santorini")
    out = tmp_path / "sfm"
    proc = subprocess.run([sys.executable, "-m", "gsgs_engine", "sfm", str(photos), "--out", str(out)],
                          cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "registered 3/3 views" in proc.stdout.splitlines()
    assert "[1/4]" in proc.stdout and "[4/4]" in proc.stdout
    # Undistorted: one PINHOLE camera, images no larger than --max-image-size, all present.
    cams = _read_colmap_cameras_bin(out / "sparse" / "0" / "cameras.bin")
    assert [c[0] for c in cams] == [1]
    model, w, h, (fx, fy, cx, cy) = cams[0]
    assert max(w, h) <= 1600 and fx > 0 and abs(cx - w / 2) < 0.05 * w
    import cv2

    for name in ("frame_00.jpg", "frame_06.jpg", "frame_12.jpg"):
        img = cv2.imread(str(out / "images" / name))
        assert img is not None and img.shape[:2] == (h, w)
    report = json.loads((out / "sfm_report.json").read_text())
    assert report["registered"] == 3 and report["num_points"] > 100
    assert report["mean_reprojection_error"] < 2.0
    # The project's COLMAP loader reads the folder as it is.
    from gsgs_engine.io import load_scene

    scene = load_scene(out, format="colmap")
    assert sorted(v.name for v in scene.views) == ["frame_00", "frame_06", "frame_12"]
    assert len(scene.points) == report["num_points"]
    assert all(abs(v.camera.fx - fx) < 1e-6 and v.camera.width == w for v in scene.views)


@pytest.mark.slow
def test_sfm_job_writes_cameras_points_and_progress(tmp_path):
    photos = shared_scene("photos_santorini")
    job = Job.create(tmp_path / "job", "sfm", data={"photos": str(photos)}, settings={"max_image_size": 800})
    result = run_sfm_job(job)
    assert result.num_registered == 3
    cams = json.loads((job.result_dir / "cameras.json").read_text())
    assert len(cams) == 3
    for entry in cams:
        cam = Camera.from_dict(entry)
        assert max(cam.width, cam.height) <= 800 and Path(entry["image"]).is_file()
    ply = _read_point_ply(job.result_dir / "points.ply")
    assert len(ply) == len(result.points) > 50
    # Every sparse point lies in front of every camera that registered (a sane SfM scene).
    pts = np.stack([ply["x"], ply["y"], ply["z"]], 1).astype(np.float64)
    for cam in result.cameras:
        _, z = cam.project(pts)
        assert np.mean(z > 0) > 0.95
    events = [json.loads(line) for line in job.progress_path.read_text().splitlines()]
    stages = [e["stage"] for e in events]
    assert [s for i, s in enumerate(stages) if i == 0 or s != stages[i - 1]] == [
        "features", "matching", "mapping", "undistortion", "export", "done"]
    mapping = [e["message"] for e in events if e["stage"] == "mapping"]  # one event per strategy tried
    assert mapping[0].startswith("incremental") and any(m.startswith("global") for m in mapping)
    assert all(e["phase"] == "sfm" for e in events) and events[-1]["registered"] == 3
    # The add-on's Info line shows this message: the count and the strategy that won.
    assert job.status()["state"] == "ok"
    assert job.status()["message"] == f"registered 3/3 views ({result.strategy})" and result.strategy
    # A few photos match on one thread, the only way COLMAP's matcher repeats: one matcher in the log
    # (with every thread, one per thread)
    assert (job.result_dir / "colmap.log").read_text().count("Creating SIFT CPU feature matcher") == 1


@pytest.mark.slow
def test_known_pose_triangulation_of_lego_training_views_reprojects(tmp_path):
    from gsgs_engine.io import load_scene

    scene = load_scene(shared_scene("lego_200"))
    views = scene.train
    assert len(views) == 8 and scene.has_alpha
    result = triangulate_with_known_poses(views, out_dir=tmp_path / "tri")
    assert result.reason == "" and len(result.points) >= 50, result
    assert result.colors.min() >= 0 and result.colors.max() <= 1
    assert (tmp_path / "tri" / "sparse" / "0" / "points3D.bin").is_file()
    # Views are numbered in name order, not in the order threaded extraction finished them: the
    # triangulator visits views by id, so that order decided the points (CI got other points under load).
    import sqlite3

    with sqlite3.connect(tmp_path / "tri" / "database.db") as db:
        ids = db.execute("select image_id, name from images order by image_id").fetchall()
    assert [name for _, name in ids] == sorted(name for _, name in ids) and len(ids) == 8
    # Reproject with gsgs' own Camera (not COLMAP's): the pose and pixel conventions agree.
    errors = []
    for point, track in zip(result.points.astype(np.float64), result.tracks):
        assert len(track) >= 2
        for k, u, v in track:
            uv, z = views[int(k)].camera.project(point[None])
            assert z[0] > 0
            errors.append(np.hypot(*(uv[0] - (u, v))))
    errors = np.array(errors)
    assert errors.mean() < 1.0 and errors.max() < 2.5, (errors.mean(), errors.max())
    # The lego model sits inside a ~1.3 unit cube around the origin; stray points are rare.
    assert np.mean(np.all(np.abs(result.points) < 1.5, axis=1)) > 0.9
    pts, cols = triangulate_known_poses(views)
    assert pts.shape[1] == 3 and cols.shape == pts.shape and len(pts) >= 50


@pytest.mark.slow
def test_unrelated_photo_is_reported_by_name_while_the_rest_register(tmp_path):
    import shutil

    photos = tmp_path / "mixed"
    photos.mkdir()
    for f in sorted(shared_scene("photos_santorini").glob("*.jpg")):
        shutil.copy(f, photos / f.name)
    flower = sorted((shared_scene("llff_flower") / "images_8").iterdir())[0]
    shutil.copy(flower, photos / f"unrelated{flower.suffix}")
    result = run_sfm(photos, tmp_path / "out", max_image_size=800)
    assert result.summary() == "registered 3/4 views"
    assert [v.name for v in result.failed] == [f"unrelated{flower.suffix}"]
    assert result.failed[0].reason.startswith("no matches") and result.failed[0].num_features > 100
    # A 504x378 photo among 1920x1080 ones cannot share one camera: each gets its own.
    assert any("different sizes" in note for note in result.notes)
    assert sorted(c.name for c in result.cameras) == ["frame_00.jpg", "frame_06.jpg", "frame_12.jpg"]
    assert sorted(p.name for p in (tmp_path / "out" / "images").iterdir()) == sorted(c.name for c in result.cameras)
