"""The artist workflow around splats: import sets the scene up for rendering (and says what it changed),
huge counts are warned about, headless jobs time out, job paths may be blend-relative."""

from __future__ import annotations

import sys
import warnings

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
from gsgs_blender import job_runner, render_setup, splat_import  # noqa: E402
from gsgs_engine.io.ply import GaussianPly, write_gaussian_ply  # noqa: E402
from test_blender_addon import addon  # noqa: E402,F401  (the registered add-on, jobs under tmp_path)

pytestmark = pytest.mark.blender

SLEEPING_ENGINE = r'''
import sys, time
from gsgs_engine.job import Job
job = Job.open(sys.argv[1])
job.set_status("running", "started")
while True:
    time.sleep(0.1)
'''


def _ply(path, n=30):
    rng = np.random.default_rng(0)
    write_gaussian_ply(path, GaussianPly(positions=rng.normal(size=(n, 3)), opacity_logits=np.zeros(n),
                                         log_scales=np.full((n, 3), -3.0), quats_wxyz=np.tile([1.0, 0, 0, 0], (n, 1)),
                                         sh_dc=np.zeros((n, 3)), sh_rest=np.zeros((n, 0, 3))))
    return path


def test_import_sets_the_scene_up_and_reports_each_change(addon, tmp_path, capsys):
    scene = addon
    scene.view_settings.view_transform = "AgX"
    scene.cycles.transparent_max_bounces = 8
    assert bpy.ops.gsgs.import_splat_ply(filepath=str(_ply(tmp_path / "s.ply"))) == {"FINISHED"}
    assert scene.view_settings.view_transform == "Raw"  # the default colour mode: exact
    assert scene.cycles.transparent_max_bounces == scene.cycles.min_transparent_bounces == 1024
    out = capsys.readouterr().out
    assert "splat render set-up: view_transform: AgX -> Raw" in out
    assert "splat render set-up: transparent_max_bounces: 8 -> 1024" in out
    obj = bpy.data.objects["s"]
    assert obj["gsgs_report"]  # what the operator reported stays on the object
    # Importing again changes nothing more, and says so by listing nothing.
    assert bpy.ops.gsgs.import_splat_ply(filepath=str(_ply(tmp_path / "t.ply"))) == {"FINISHED"}
    assert "splat render set-up" not in capsys.readouterr().out
    # The operator switches the colour mode on the scene and every splat object.
    assert bpy.ops.gsgs.setup_splat_render(colour_mode="LINEAR") == {"FINISHED"}
    assert scene.view_settings.view_transform == "Standard"
    assert "Linear Colours: False -> True" in capsys.readouterr().out


def test_import_can_leave_the_scene_alone(addon, tmp_path):
    scene = addon
    scene.gsgs.setup_render_on_import = False
    scene.view_settings.view_transform = "AgX"
    assert bpy.ops.gsgs.import_splat_ply(filepath=str(_ply(tmp_path / "s.ply"))) == {"FINISHED"}
    assert scene.view_settings.view_transform == "AgX"
    assert render_setup.pending_changes(scene)  # what the Set Up operator would still change


def test_large_counts_are_warned_about():
    assert splat_import.count_warning(splat_import.LARGE_COUNT, "x.ply") is None
    text = splat_import.count_warning(611_000, "x.ply")
    assert "611,000 splats" in text and "pseudo views" in text


def test_headless_job_gives_up_after_its_timeout(addon, tmp_path, monkeypatch):
    script = tmp_path / "sleeping_engine.py"
    script.write_text(SLEEPING_ENGINE)
    monkeypatch.setattr(job_runner, "engine_command", lambda python, job_dir: [sys.executable, str(script), str(job_dir)])
    monkeypatch.setattr(job_runner, "CANCEL_GRACE_S", 0.5)
    monkeypatch.setattr(job_runner, "KILL_GRACE_S", 0.5)
    scene = addon
    scene.gsgs.validate_source = str(tmp_path)
    with pytest.raises(RuntimeError, match="still running after 1 s"):
        bpy.ops.gsgs.validate(timeout=1.0)
    run = job_runner.attach(bpy.path.abspath(scene.gsgs.validate_job))
    assert run.finished  # cancelled and terminated, not left running


def test_job_paths_may_be_blend_relative(addon):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for name in ("sfm_job", "train_job", "validate_job", "photos_dir", "validate_source"):
            setattr(addon.gsgs, name, "//gsgs_jobs/x")


def test_train_panel_states_the_time_and_unused_path_poses_before_starting(addon):
    from test_blender_addon import _draw_all, _lego_cameras

    scene = addon
    _lego_cameras(scene)
    bpy.ops.gsgs.use_scene_cameras()
    bpy.ops.gsgs.make_pseudo_path(closed=True)
    bpy.ops.gsgs.sample_pseudo_poses()
    labels = [kw.get("text", "") for name, _, kw in _draw_all(bpy.context) if name == "label"]
    estimate = [t for t in labels if t.startswith("Estimated: ~")]
    assert estimate and "1000 steps of the orbit recipe on 200x200 px" in estimate[0], labels  # the balanced preset on lego
    # sparse points out at the cameras' shell (the walls of a room around them): the inward shell's recipe is stated
    rng = np.random.default_rng(0)
    wall = rng.normal(size=(100, 3))
    wall = 4.0 * wall / np.linalg.norm(wall, axis=1, keepdims=True)
    mesh = bpy.data.meshes.new("wall_points")
    mesh.from_pydata([tuple(map(float, p)) for p in wall], [], [])
    points = bpy.data.objects.new("wall_points", mesh)
    scene.collection.objects.link(points)
    scene.gsgs.points_object = points
    labels = [kw.get("text", "") for name, _, kw in _draw_all(bpy.context) if name == "label"]
    assert any("1000 steps of the inward-shell recipe on 200x200 px" in t for t in labels), labels
    points.scale = (0.2, 0.2, 0.2)  # the same points inside the rig (an object): the orbit's again
    bpy.context.view_layer.update()
    labels = [kw.get("text", "") for name, _, kw in _draw_all(bpy.context) if name == "label"]
    assert any("1000 steps of the orbit recipe on 200x200 px" in t for t in labels), labels
    scene.gsgs.points_object = None
    scene.gsgs.generator = "none"
    labels = [kw.get("text", "") for name, _, kw in _draw_all(bpy.context) if name == "label"]
    assert any("path poses are unused" in t for t in labels)  # no generator: the path is not used
    scene.gsgs.generator = "warp"
    labels = [kw.get("text", "") for name, _, kw in _draw_all(bpy.context) if name == "label"]
    assert not any("path poses are unused" in t for t in labels)
