"""The add-on's multi-view video import (real bpy): a Panoptic capture's training cameras as Blender
cameras, the frame range as the capture's frames, a 4D training job that names the folder, and the 4D
result playing on the timeline."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
from gsgs_blender import camera_convert, job_runner, pseudo_paths, timeline  # noqa: E402
from test_blender_addon import addon  # noqa: E402,F401  (the registered add-on, jobs under tmp_path)
from gsgs_engine.io import load_scene  # noqa: E402
from gsgs_engine.job import Job  # noqa: E402
from tests.test_io_panoptic import TEST_IDS, write_capture  # noqa: E402
from tests.test_io_scenes import tiny_nerf  # noqa: E402

pytestmark = pytest.mark.blender


@pytest.fixture
def pano(tmp_path):
    return write_capture(tmp_path / "pano", frames=4)


def test_import_makes_the_training_cameras_and_the_frame_range(addon, pano):
    scene = addon
    s = scene.gsgs
    s.video_dir, s.video_train_cameras, s.video_frames = str(pano), 3, "1-3"
    assert bpy.ops.gsgs.import_video() == {"FINISHED"}
    objs = pseudo_paths.training_camera_objects(scene)
    engine = load_scene(pano, train_views=3, frames="1-3")
    first = {v.camera.extra["camera_index"]: v for v in engine.train if v.camera.extra["frame"] == 1}
    assert sorted(o.name for o in objs) == [f"cam_{i}" for i in sorted(first)]
    for obj in objs:
        view = first[int(obj.name.split("_")[1])]
        cam = camera_convert.camera_from_object(obj, scene)
        np.testing.assert_allclose(cam.center * 1.0, view.camera.center * engine.world_scale, atol=1e-4)
        np.testing.assert_allclose(cam.R, view.camera.R, atol=1e-5)
        assert obj[camera_convert.PROP_IMAGE] == str(view.image_path)  # frame 1's image as background
    assert (scene.frame_start, scene.frame_end) == (1, 3)  # the capture's frame ids: the 4D result's time
    assert s.video_source == str(pano)
    # Train writes a job that names the folder, the protocol and the frames (no inline photos, no path poses)
    from gsgs_blender.ops_train import train_spec

    spec = train_spec(bpy.context)
    assert spec["data"] == {"path": str(pano.resolve()), "format": "auto", "background": [1.0, 1.0, 1.0],
                            "train_views": 3, "frames": "1-3"}
    assert spec["pseudo_poses"] == []
    # the Train panel's time estimate is the 4D recipe's
    from gsgs_blender import train_estimate

    assert train_estimate.job_estimate_inputs(scene)["video"]
    assert "of the 4D recipe" in train_estimate.estimate_text(scene)
    # importing again replaces the cameras; then using scene cameras makes the job a photo job again
    s.video_train_cameras = 2
    assert bpy.ops.gsgs.import_video() == {"FINISHED"}
    assert len(pseudo_paths.training_camera_objects(scene)) == 2
    assert len([o for o in bpy.data.objects if o.type == "CAMERA"]) == 2
    assert bpy.ops.gsgs.use_scene_cameras() == {"FINISHED"}
    assert s.video_source == "" and train_spec(bpy.context)["data"]["format"] == "job"
    assert not train_estimate.job_estimate_inputs(scene)["video"]


def test_bad_folders_are_refused_with_the_reason(addon, tmp_path):
    s = addon.gsgs
    s.video_dir = str(tmp_path / "missing")
    with pytest.raises(RuntimeError, match="not a folder"):
        bpy.ops.gsgs.import_video()
    s.video_dir = str(tiny_nerf(tmp_path / "static"))
    with pytest.raises(RuntimeError, match="carry no time"):
        bpy.ops.gsgs.import_video()
    assert not pseudo_paths.training_camera_objects(addon) and s.video_source == ""


@pytest.mark.slow
def test_train_on_the_video_imports_a_4d_result_that_plays(addon, pano):
    scene = addon
    s = scene.gsgs
    s.video_dir, s.video_train_cameras = str(pano), 3
    assert bpy.ops.gsgs.import_video() == {"FINISHED"}
    s.preset = "custom"
    s.iterations, s.generator = 8, "none"
    assert bpy.ops.gsgs.train() == {"FINISHED"}  # headless: waits for the job
    run = job_runner.attach(bpy.path.abspath(s.train_job))
    assert run.state == "ok", run.message
    metrics = json.loads((Path(bpy.path.abspath(s.train_job)) / "result" / "metrics.json").read_text())
    assert metrics["plan"]["effects"]["time"]["enabled"] is True  # the engine trained a 4D model
    assert Job.open(bpy.path.abspath(s.train_job)).spec["data"]["train_views"] == 3
    obj = s.result_object
    assert obj is not None and timeline.playable(obj)
    assert (obj[timeline.FRAME_START], obj[timeline.FRAME_END]) == (0, 3)
    scene.frame_set(0)
    at_start = np.array([v.co[:] for v in obj.data.vertices])
    scene.frame_set(3)
    assert timeline.update_object(obj, 3) == 1.0
    assert np.array([v.co[:] for v in obj.data.vertices]).shape == at_start.shape
