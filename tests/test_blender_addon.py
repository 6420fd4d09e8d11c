"""The add-on with the real bpy module: registration, sidebar, operators, the job folder it writes."""

from __future__ import annotations

import ast
import json
import re
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO, shared_scene

bpy = pytest.importorskip("bpy")
import gsgs_blender  # noqa: E402  (needs bpy)
from gsgs_blender import camera_convert, job_runner, operators, ops_common, panels, pseudo_paths  # noqa: E402

pytestmark = pytest.mark.blender
ADDON_DIR = REPO / "gsgs_blender"


@pytest.fixture()
def addon(tmp_path, monkeypatch):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    gsgs_blender.register()
    from gsgs_blender import preferences

    # Without the add-on system the preferences are the fallback object: point it at this checkout.
    monkeypatch.setattr(preferences._FALLBACK, "jobs_dir", str(tmp_path / "jobs"))
    monkeypatch.setattr(preferences._FALLBACK, "python_path", sys.executable)
    monkeypatch.setattr(preferences._FALLBACK, "engine_root", str(REPO))
    yield bpy.context.scene
    gsgs_blender.unregister()
    job_runner.RUNS.clear()
    bpy.ops.wm.read_factory_settings(use_empty=True)


def test_register_unregister_twice():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for _ in range(2):
        gsgs_blender.register()
        assert hasattr(bpy.types, "GSGS_PT_photos") and hasattr(bpy.types.Scene, "gsgs")
        assert bpy.ops.gsgs.train.idname() == "GSGS_OT_train"
        assert bpy.context.scene.gsgs.pseudo_count == 16
        gsgs_blender.unregister()
        assert not hasattr(bpy.types, "GSGS_PT_photos") and not hasattr(bpy.types.Scene, "gsgs")
        assert not hasattr(bpy.types, "GSGS_OT_train")


def test_sidebar_order_and_location():
    ordered = sorted(panels.CLASSES, key=lambda c: c.bl_order)
    assert [c.bl_label for c in ordered] == ["Photos", "Cameras", "Pseudo Paths", "Train", "Result", "Validate"]
    assert {(c.bl_space_type, c.bl_region_type, c.bl_category) for c in panels.CLASSES} == {("VIEW_3D", "UI", "GS-GS")}


def test_every_operator_has_a_tooltip():
    for cls in operators.all_classes():
        assert cls.bl_description.strip(), cls.__name__
        assert cls.bl_idname.startswith("gsgs."), cls.__name__


def test_disabled_operators_say_why(addon):
    assert not bpy.ops.gsgs.train.poll()
    with pytest.raises(RuntimeError, match="No training cameras"):
        bpy.ops.gsgs.train()
    with pytest.raises(RuntimeError, match="photos folder"):
        bpy.ops.gsgs.import_photos()


def test_addon_modules_never_import_heavy_packages():
    heavy = {"torch", "cv2", "pycolmap", "diffusers", "transformers"}
    for path in ADDON_DIR.glob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            for name in names:
                assert name.split(".")[0] not in heavy, f"{path.name} imports {name}"


def _lego_cameras(scene, ids=(0, 2, 4, 6)):
    from gsgs_engine.cameras import camera_from_nerf

    root = shared_scene("lego_200")
    meta = json.loads((root / "transforms_train.json").read_text())
    coll = scene.collection
    objs, cams = [], []
    for i in ids:
        frame = meta["frames"][i]
        cam = camera_from_nerf(np.array(frame["transform_matrix"]), 200, 200, camera_angle_x=meta["camera_angle_x"],
                               name=f"lego_{i}")
        obj = camera_convert.new_camera_object(cam, coll, scene)
        image = str((root / (frame["file_path"] + ".png")).resolve())
        img = bpy.data.images.load(image)
        bg = obj.data.background_images.new()
        bg.image = img
        objs.append(obj)
        cams.append((cam, image))
    return objs, cams


def test_known_poses_pseudo_path_and_train_job(addon, tmp_path):
    from gsgs_engine.io import load_scene
    from gsgs_engine.job import Job

    scene = addon
    objs, cams = _lego_cameras(scene)
    assert bpy.ops.gsgs.use_scene_cameras() == {"FINISHED"}
    assert len(pseudo_paths.training_camera_objects(scene)) == 4
    assert bpy.ops.gsgs.make_pseudo_path(closed=True) == {"FINISHED"}
    scene.gsgs.pseudo_count = 12
    assert bpy.ops.gsgs.sample_pseudo_poses() == {"FINISHED"}
    poses = pseudo_paths.poses_from_json(scene.gsgs.pseudo_poses)
    assert len(poses) == 12
    by_name = {c.name: c for c, _ in cams}
    from gsgs_engine.cameras import Camera

    for pose in poses:
        cam = Camera.from_dict(pose)
        nearest = by_name[pose["nearest"]]
        # Blender stores lens in float32: equal to ~1e-7 relative.
        np.testing.assert_allclose([cam.fx, cam.cx, cam.width], [nearest.fx, nearest.cx, nearest.width], rtol=1e-6)
        # The lego cameras look at the origin: every pseudo camera's axis passes through it.
        axis_to_origin = -cam.center - (-cam.center @ cam.R[2]) * cam.R[2]
        assert np.linalg.norm(axis_to_origin) < 0.05
    # The path passes through the cameras: the first pose sits on the first camera of the ring.
    positions = np.array([c.center for c, _ in sorted(cams, key=lambda c: c[0].name)])
    first = positions[pseudo_paths.ring_order(positions)[0]]
    np.testing.assert_allclose(Camera.from_dict(poses[0]).center, first, atol=1e-4)

    from gsgs_blender.ops_train import train_spec

    job = Job.create(tmp_path / "train_job", "train", **train_spec(bpy.context))
    loaded = load_scene(job.root)  # the engine reads what the add-on wrote
    assert len(loaded.train) == 4 and len(job.spec["pseudo_poses"]) == 12
    for view, (cam, image) in zip(loaded.train, sorted(cams, key=lambda c: c[0].name)):
        np.testing.assert_allclose(view.camera.R, cam.R, atol=1e-6)
        np.testing.assert_allclose(view.camera.t, cam.t, atol=1e-6)
        assert view.camera.fx == pytest.approx(cam.fx, rel=1e-6)
        assert Path(view.image_path).resolve() == Path(image)
    settings = job.spec["settings"]
    # The panel starts from the balanced preset: the engine's default schedule, not the paper's 10,000 steps.
    assert settings["preset"] == "balanced" and settings["iters"] == 1000 and settings["prior"] == "auto"
    scene.gsgs.generator = "warp"  # editing a field makes the preset Custom
    scene.gsgs.rounds = 2
    assert scene.gsgs.preset == "custom"
    settings = train_spec(bpy.context)["settings"]
    assert settings["prior"] == "warp" and settings["prior_settings"]["rounds"] == 2 and settings["iters"] == 1000


def test_slerp_orientation_stays_between_neighbours(addon):
    scene = addon
    _lego_cameras(scene)
    bpy.ops.gsgs.use_scene_cameras()
    bpy.ops.gsgs.make_pseudo_path(closed=False, kind="POLY")
    scene.gsgs.pseudo_orientation = "SLERP"
    scene.gsgs.pseudo_count = 5
    bpy.ops.gsgs.sample_pseudo_poses()
    poses = pseudo_paths.poses_from_json(scene.gsgs.pseudo_poses)
    objs = pseudo_paths.training_camera_objects(scene)
    order = pseudo_paths.ring_order(np.array([np.asarray(o.matrix_world)[:3, 3] for o in objs]))
    first = camera_convert.camera_from_object(objs[order[0]], scene)
    # The open path starts at the first camera: the first pose is that camera.
    np.testing.assert_allclose(np.array(poses[0]["R"]), first.R, atol=1e-5)
    np.testing.assert_allclose(np.array(poses[0]["t"]), first.t, atol=1e-4)


@pytest.mark.slow
def test_check_engine_reports_versions():
    from gsgs_blender.preferences import check_engine

    ok, report = check_engine(sys.executable, str(REPO))
    assert ok, report
    import torch

    assert f"torch {torch.__version__}" in report and "pycolmap" in report


def test_check_engine_with_a_bad_interpreter(tmp_path):
    from gsgs_blender.preferences import check_engine

    ok, report = check_engine(str(tmp_path / "python-nope"))
    assert not ok and "no such interpreter" in report


@pytest.mark.slow
def test_train_operator_headless_runs_the_engine_and_imports_the_result(addon):
    scene = addon
    _lego_cameras(scene, ids=(0, 1, 2, 3, 4, 5))
    bpy.ops.gsgs.use_scene_cameras()
    scene.gsgs.iterations = 30
    scene.gsgs.resolution_scale = 0.25
    scene.gsgs.generator = "none"  # the plain trainer: quick; the prior has its own tests
    assert bpy.ops.gsgs.train() == {"FINISHED"}  # headless: waits for the job
    run = job_runner.attach(bpy.path.abspath(scene.gsgs.train_job))
    assert run.state == "ok", run.message
    obj = scene.gsgs.result_object
    assert obj is not None and obj["gsgs_count"] > 0
    assert len(obj.data.vertices) == obj["gsgs_count"]
    from gsgs_blender import train_estimate

    estimate = json.loads((Path(run.job_dir) / train_estimate.ESTIMATE_FILE).read_text())
    assert estimate["recipe"] == "plain" and estimate["iterations"] == 30 and estimate["estimated_s"] > 0
    # scaled by the machine probe the operator ran first (1.0 where the kernel was not built yet to probe with)
    assert estimate["estimated_s"] == pytest.approx(estimate["reference_s"] * estimate["probe_factor"])
    assert "too short" in train_estimate.learn_from_job(run.job_dir)  # 30 steps do not time the machine
    metrics = json.loads((Path(run.job_dir) / "result" / "metrics.json").read_text())
    assert metrics["plan"]["backend"] in ("cpu", "reference")  # where learn_from_job reads the renderer a job used
    assert train_estimate.read_timings() == []


@pytest.mark.slow
def test_import_photos_headless_creates_posed_cameras_and_points(addon):
    """Photos -> SfM job (real engine child) -> camera objects whose projection of the sparse points
    lands inside their photos, each photo as background, and the point cloud object."""
    from gsgs_engine.job import Job

    scene = addon
    scene.gsgs.photos_dir = str(shared_scene("photos_santorini"))
    scene.gsgs.max_image_size = 480
    assert bpy.ops.gsgs.import_photos() == {"FINISHED"}  # headless: waits for the job
    assert Job.open(bpy.path.abspath(scene.gsgs.sfm_job)).status()["state"] == "ok"
    objs = pseudo_paths.training_camera_objects(scene)
    assert len(objs) >= 2
    pts_obj = scene.gsgs.points_object
    assert pts_obj is not None and len(pts_obj.data.vertices) > 20
    co = np.empty(len(pts_obj.data.vertices) * 3, np.float32)
    pts_obj.data.vertices.foreach_get("co", co)
    pts = co.reshape(-1, 3)
    from gsgs_blender.ops_photos import read_cameras_json

    solved = {c.name: (c, image) for c, image in
              read_cameras_json(Path(bpy.path.abspath(scene.gsgs.sfm_job)) / "result" / "cameras.json")}
    assert sorted(solved) == sorted(o.name for o in objs)
    for obj in objs:
        assert obj.data.show_background_images and obj.data.background_images[0].image is not None
        cam = camera_convert.camera_from_object(obj, scene)
        ref, image = solved[obj.name]
        assert obj["gsgs_image"] == image
        np.testing.assert_allclose(cam.R, ref.R, atol=1e-6)
        np.testing.assert_allclose(cam.t, ref.t, atol=1e-5)
        np.testing.assert_allclose([cam.fx, cam.fy, cam.cx, cam.cy], [ref.fx, ref.fy, ref.cx, ref.cy], rtol=1e-6)
        assert max(cam.width, cam.height) <= 480
        uv, z = cam.project(pts)
        inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= cam.height)
        assert inside.mean() > 0.5, f"{obj.name}: only {inside.mean():.0%} of the points project into its photo"


# -- the extension package -----------------------------------------------------------------------

def _build(tmp_path) -> Path:
    sys.path.insert(0, str(REPO / "scripts"))
    try:
        import build_extension
    finally:
        sys.path.pop(0)
    return build_extension.build(tmp_path / "dist")


def test_manifest_fields():
    import tomllib

    m = tomllib.loads((REPO / "blender_manifest.toml").read_text())
    assert m["schema_version"] == "1.0.0" and m["id"] == "gsgs" and m["type"] == "add-on"
    assert m["blender_version_min"] == "4.2.0" and m["license"] == ["SPDX:GPL-3.0-or-later"]
    assert m["name"] and m["maintainer"] and m["tagline"]
    assert len(m["tagline"]) <= 64 and m["tagline"][-1].isalnum()  # Blender rejects trailing punctuation
    assert m["permissions"]["files"] and not m["permissions"]["files"].endswith(".")
    import gsgs_engine

    assert m["version"] == gsgs_engine.__version__
    assert m["wheels"] == [f"./wheels/gsgs_engine_core-{gsgs_engine.__version__}-py3-none-any.whl"]


def test_extension_zip_contents(tmp_path):
    import base64
    import hashlib
    import io
    import zipfile

    path = _build(tmp_path)
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        wheel_name = next(n for n in names if n.startswith("wheels/") and n.endswith(".whl"))  # not engine/
        wheel = zipfile.ZipFile(io.BytesIO(zf.read(wheel_name)))
    assert "blender_manifest.toml" in names and "__init__.py" in names
    assert {p.name for p in ADDON_DIR.glob("*.py")} <= names
    assert not any(n.startswith("gsgs_blender/") or "__pycache__" in n for n in names)
    wnames = set(wheel.namelist())
    needed = {"gsgs_engine/__init__.py", "gsgs_engine/cameras.py", "gsgs_engine/job.py",
              "gsgs_engine/io/__init__.py", "gsgs_engine/io/scene.py", "gsgs_engine/io/ply.py"}
    assert needed <= wnames
    assert not any(n.startswith(("gsgs_engine/render", "gsgs_engine/train", "gsgs_engine/priors")) for n in wnames)
    # RECORD hashes match the files, as installers check.
    record = next(n for n in wnames if n.endswith("RECORD"))
    for line in wheel.read(record).decode().splitlines():
        name, digest, size = line.split(",")
        if digest:
            data = wheel.read(name)
            assert digest == "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
            assert int(size) == len(data)
    # Nothing in the wheel imports a heavy package at module level.
    for name in wnames:
        if name.endswith(".py"):
            tree = ast.parse(wheel.read(name))
            for node in tree.body:
                mods = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                    [node.module or ""] if isinstance(node, ast.ImportFrom) else []
                assert not any(m.split(".")[0] in {"torch", "cv2", "pycolmap", "bpy"} for m in mods), name


def test_extension_zip_passes_blenders_validator(tmp_path):
    import subprocess

    cli = Path(bpy.utils.system_resource("SCRIPTS")) / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    if not cli.is_file():
        pytest.skip(f"Blender's extension tool not found at {cli}")
    path = _build(tmp_path)
    out = subprocess.run([sys.executable, str(cli), "validate", str(path)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0 and "Success" in out.stdout, out.stdout + out.stderr


@pytest.mark.slow
def test_extension_installs_and_enables_through_blender(tmp_path):
    """Blender's own "Install from Disk" (extensions.package_install_files) in a private user
    folder: the wheel lands in the extension site-packages, the add-on enables as
    bl_ext.user_default.gsgs with its preferences, and disables cleanly."""
    import os
    import subprocess

    path = _build(tmp_path)
    code = (
        "import sys, bpy, addon_utils\n"
        "r = bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo='user_default', "
        "enable_on_install=True)\n"
        "assert r == {'FINISHED'}, r\n"
        "mod = 'bl_ext.user_default.gsgs'\n"
        "prefs = bpy.context.preferences.addons[mod].preferences\n"
        "import gsgs_engine\n"
        "print('ENGINE', gsgs_engine.__file__)\n"
        "print('PYTHON', prefs.python_path)\n"
        "assert bpy.context.scene.gsgs.pseudo_count == 16 and not bpy.ops.gsgs.train.poll()\n"
        "addon_utils.disable(mod)\n"
        "assert not hasattr(bpy.types.Scene, 'gsgs')\n"
        "print('INSTALLED-AND-ENABLED')\n")
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(tmp_path),
           "BLENDER_USER_RESOURCES": str(tmp_path / "blender_user")}
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=300,
                         cwd=tmp_path, env=env)
    assert "INSTALLED-AND-ENABLED" in out.stdout, out.stdout[-2000:] + out.stderr[-2000:]
    engine = next(line for line in out.stdout.splitlines() if line.startswith("ENGINE "))
    assert str(tmp_path / "blender_user") in engine  # from the wheel, not this checkout
    assert "PYTHON python3" in out.stdout  # no checkout next to an installed extension


# -- the sidebar drawing code (no window in tests: a recording stand-in for UILayout) -------------

class _Layout:
    """Records UILayout calls; checks the method names exist on the real bpy.types.UILayout."""

    def __init__(self, log):
        self.log = log

    def __getattr__(self, name):
        if name not in bpy.types.UILayout.bl_rna.functions:
            raise AttributeError(f"UILayout has no {name}()")

        def call(*args, **kwargs):
            self.log.append((name, args, kwargs))
            return _Layout(self.log)
        return call

    def __setattr__(self, name, value):
        object.__setattr__(self, name, value)


def _draw_all(context) -> list:
    log = []
    for cls in panels.CLASSES:
        cls.draw(type("P", (), {"layout": _Layout(log)})(), context)
    return log


def test_panels_draw_job_states(addon, tmp_path):
    from gsgs_engine.job import Job

    assert "progress" in bpy.types.UILayout.bl_rna.functions  # layout.progress exists since Blender 4.0
    scene = addon
    assert _draw_all(bpy.context)  # nothing set up yet
    job = Job.create(tmp_path / "train", "train", data={"path": "x"})
    job.emit("train", 250, 1000, losses={"l1": 0.05, "psnr": 24.5}, eta_s=75)
    job.set_status("running", "training")
    scene.gsgs.train_job = str(job.root)
    log = _draw_all(bpy.context)
    bars = [kw for name, _, kw in log if name == "progress"]
    assert bars and bars[0]["factor"] == pytest.approx(0.25) and "250/1000" in bars[0]["text"]
    labels = [kw.get("text", "") for name, _, kw in log if name == "label"]
    assert "l1 0.05, psnr 24.5" in labels and "ETA 1:15" in labels
    assert any(name == "operator" and args[0] == "gsgs.cancel_job" for name, args, _ in log)

    job_runner.RUNS.clear()
    (job.root / "log.txt").write_text("step 1\nTraceback (most recent call last):\nValueError: bad thing\n")
    job.set_status("error", "ValueError: bad thing (see log.txt)")
    log = _draw_all(bpy.context)
    labels = [kw.get("text", "") for name, _, kw in log if name == "label"]
    assert "ValueError: bad thing (see log.txt)" in labels and "ValueError: bad thing" in labels
    assert any(name == "operator" and args[0] == "gsgs.resume_job" for name, args, _ in log)


def test_frustum_lines_reach_the_image_corners():
    from gsgs_engine.cameras import Camera, look_at

    R, t = look_at(np.array([3.0, -2.0, 1.0]), np.zeros(3))
    cam = Camera(R=R, t=t, fx=300, fy=320, cx=170, cy=110, width=320, height=240)
    segs = pseudo_paths.frustum_lines(cam, depth=0.7)
    corners = segs[[1, 3, 5, 7]]
    uv, z = cam.project(corners)
    np.testing.assert_allclose(uv, [[0, 0], [320, 0], [320, 240], [0, 240]], atol=1e-3)
    np.testing.assert_allclose(z, 0.7, atol=1e-5)


@pytest.mark.slow
def test_reconstruct_script_end_to_end(tmp_path):
    import subprocess

    photos = shared_scene("photos_santorini")
    out = subprocess.run([sys.executable, str(REPO / "scripts" / "reconstruct.py"), "--photos", str(photos),
                          "--out", str(tmp_path / "out"), "--iters", "5", "--resolution-scale", "0.25",
                          "--max-image-size", "320", "--pseudo-views", "4", "--prior", "none",
                          "--python", sys.executable],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert (tmp_path / "out" / "scene.blend").is_file()
    assert "reconstruct: ok" in out.stdout and " splats, " in out.stdout
    # stated before training, after the machine probe (which leaves it unprobed while the kernel is not built yet)
    assert re.search(r"estimated ~.* on (this machine \(its speed probed\)|a 2-core CPU)", out.stdout), out.stdout
    train_jobs = list((tmp_path / "out" / "jobs").glob("train-*/job.json"))
    assert len(train_jobs) == 1 and len(json.loads(train_jobs[0].read_text())["pseudo_poses"]) == 4


# -- operators against a stand-in engine (same folder protocol, instant) ---------------------------

FAKE_ENGINE = r'''
import json, sys
import numpy as np
from gsgs_engine.job import Job
from gsgs_engine.io.ply import GaussianPly, write_gaussian_ply
job = Job.open(sys.argv[1])
job.set_status("running", "started")
job.emit("train", 1, 1, losses={"l1": 0.1})
n = 64
rng = np.random.default_rng(0)
write_gaussian_ply(job.result_dir / "point_cloud.ply", GaussianPly(
    positions=rng.normal(size=(n, 3)), opacity_logits=np.zeros(n), log_scales=np.full((n, 3), -3.0),
    quats_wxyz=np.tile([1.0, 0, 0, 0], (n, 1)), sh_dc=np.zeros((n, 3)), sh_rest=np.zeros((n, 0, 3))))
(job.result_dir / "metrics.json").write_text(json.dumps({"psnr": 21.5, "ssim": 0.8, "lpips": None}))
(job.root / "seen_spec.json").write_text(json.dumps(job.spec))
job.set_status("ok", "fake finished")
'''


@pytest.fixture()
def fake_engine(tmp_path, monkeypatch):
    script = tmp_path / "fake_engine.py"
    script.write_text(FAKE_ENGINE)
    monkeypatch.setattr(job_runner, "engine_command", lambda python, job_dir: [sys.executable, str(script), str(job_dir)])
    return script


def test_finished_job_imports_its_result_from_the_polling_callback(addon, fake_engine, tmp_path):
    """The interactive path without a window: start with no wait, poll as the timer does, the
    on_finish callback imports the splats only once the status is ok."""
    from gsgs_blender.ops_result import import_job_result
    from gsgs_blender.ops_train import _on_train_finished
    from gsgs_engine import GsgsError
    from gsgs_engine.job import Job

    scene = addon
    job = Job.create(tmp_path / "job", "train", data={"path": "x"})
    scene.gsgs.train_job = str(job.root)
    with pytest.raises(GsgsError, match="imported only after"):
        import_job_result(scene, job.root)  # no status yet
    run = job_runner.start(job.root, sys.executable, engine_root=REPO, use_timer=False,
                           on_finish=ops_common.scene_callback(scene.name, _on_train_finished))
    for _ in range(600):  # what bpy.app.timers would call every TIMER_INTERVAL_S
        if job_runner._timer() is None:
            break
        time.sleep(0.05)
    assert run.state == "ok" and "imported 64 splats" in run.message
    assert scene.gsgs.result_object["gsgs_count"] == 64


def test_validate_operator_writes_the_job_and_shows_metrics(addon, fake_engine):
    scene = addon
    scene.gsgs.validate_source = str(shared_scene("lego_200"))
    scene.gsgs.validate_views = 8
    scene.gsgs.iterations = 123
    assert bpy.ops.gsgs.validate() == {"FINISHED"}
    root = Path(bpy.path.abspath(scene.gsgs.validate_job))
    spec = json.loads((root / "seen_spec.json").read_text())
    assert spec["task"] == "validate" and spec["data"]["train_views"] == 8
    assert spec["settings"]["iters"] == 123 and spec["settings"]["prior"] == "auto"  # the balanced preset's
    assert panels._metrics(scene.gsgs.validate_job) == "PSNR 21.50  SSIM 0.800"  # LPIPS null: not shown


def test_resume_operator_runs_the_same_folder_again(addon, fake_engine, tmp_path):
    from gsgs_engine.job import Job

    scene = addon
    job = Job.create(tmp_path / "job", "train", data={"path": "x"})
    job.set_status("cancelled", "cancelled at step 3")
    scene.gsgs.train_job = str(job.root)
    assert bpy.ops.gsgs.resume_job(kind="train") == {"FINISHED"}
    assert job.status()["state"] == "ok"
    assert scene.gsgs.result_object["gsgs_count"] == 64  # the finished resume imported its result


def test_loading_a_solve_replaces_only_its_own_cameras(addon, tmp_path):
    """A finished SfM job folder -> cameras with photos; loading again replaces them, while a user's
    camera that was in the training collection stays in the scene."""
    from gsgs_blender.ops_photos import load_sfm_result
    from gsgs_engine.cameras import Camera, look_at
    from gsgs_engine.io.ply import write_ply_vertices
    from gsgs_engine.job import Job

    scene = addon
    photos = sorted((shared_scene("lego_200") / "train").glob("*.png"))[:3]
    job = Job.create(tmp_path / "sfm", "sfm", data={"photos": str(photos[0].parent)})
    job.result_dir.mkdir(parents=True)
    cams = []
    for k, photo in enumerate(photos):
        R, t = look_at(np.array([4.0 * np.cos(k), 4.0 * np.sin(k), 1.0]), np.zeros(3))
        cams.append({**Camera(R=R, t=t, fx=250, fy=250, cx=100, cy=100, width=200, height=200,
                              name=photo.name).to_dict(), "image": str(photo)})
    (job.result_dir / "cameras.json").write_text(json.dumps(cams))
    rng = np.random.default_rng(0)
    write_ply_vertices(job.result_dir / "points.ply", {"x": rng.normal(size=30).astype(np.float32),
                                                       "y": rng.normal(size=30).astype(np.float32),
                                                       "z": rng.normal(size=30).astype(np.float32)})
    job.set_status("ok", "registered 3/3 views")
    objs, pts = load_sfm_result(scene, job.root)
    assert [o.name for o in objs] == [p.name for p in photos] and len(pts.data.vertices) == 30
    assert (scene.render.resolution_x, scene.render.resolution_y) == (200, 200)
    assert all(o.data.background_images[0].image.filepath == str(p) for o, p in zip(objs, photos))
    user_cam = bpy.data.objects.new("mine", bpy.data.cameras.new("mine"))
    scene.gsgs.camera_collection.objects.link(user_cam)
    objs, _ = load_sfm_result(scene, job.root)
    assert sorted(o.name for o in scene.gsgs.camera_collection.objects if o.type == "CAMERA") == \
        sorted(p.name for p in photos)
    assert bpy.data.objects.get("mine") is not None and bpy.data.objects["mine"].users_collection
    # The training job names the solve's sparse points while the points object stays in place.
    from gsgs_blender.ops_train import train_spec

    scene.gsgs.sfm_job = str(job.root)
    assert train_spec(bpy.context)["data"]["points"] == str(job.result_dir / "points.ply")
    scene.gsgs.points_object.location.x += 1.0
    bpy.context.view_layer.update()
    assert "points" not in train_spec(bpy.context)["data"]
