"""The engine's background sphere in Blender (gsgs_blender/background_sphere.py): a real Cycles render of the
imported sphere against the engine's own lookup of the same texture, in both colour modes, and the job import."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from gsgs_engine.cameras import Camera, look_at
from gsgs_engine.train.background_sphere import BackgroundSphere

bpy = pytest.importorskip("bpy")
from gsgs_blender import background_sphere, camera_convert, render_setup  # noqa: E402

pytestmark = pytest.mark.blender


@pytest.fixture(autouse=True)
def empty_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene
    bpy.ops.wm.read_factory_settings(use_empty=True)


CENTRE, RADIUS = np.array([0.3, -0.2, 0.1]), 3.0


def _camera(eye, target, w=24, h=16, name="c") -> Camera:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float))
    f = 0.9 * w
    return Camera(R=R, t=t, fx=f, fy=f, cx=w / 2, cy=h / 2, width=w, height=h, name=name)


def _result(tmp_path) -> tuple[BackgroundSphere, dict]:
    """A smooth random texture on the sphere, written as a run writes it; the record metrics.json holds."""
    g = torch.Generator().manual_seed(0)
    coarse = torch.randn(3, 4, 8, generator=g) * 1.2
    logits = torch.nn.functional.interpolate(coarse[None], size=(16, 32), mode="bilinear", align_corners=False)[0]
    sphere = BackgroundSphere(CENTRE, RADIUS, logits)
    sphere.write_texture(tmp_path / "background_sphere.png")
    record = sphere.describe()
    (tmp_path / "metrics.json").write_text(json.dumps({"plan": {"background_sphere": record}}))
    # what the engine composites: the texture as written (16-bit) and read back, as gsgs eval sees it
    return BackgroundSphere.from_record(record, tmp_path), record


def _cycles(scene, cam: Camera, path) -> np.ndarray:
    import cv2

    obj = camera_convert.new_camera_object(cam, scene.collection, scene)
    camera_convert.apply_camera_to_object(cam, obj, scene, set_scene_frame=True)  # the render's size too
    scene.camera = obj
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.render.threads_mode = "FIXED"
    scene.render.threads = 1
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "16"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    return img[..., ::-1].astype(np.float32) / 65535.0


@pytest.mark.parametrize("mode", ["EXACT", "LINEAR"])
def test_a_cycles_render_of_the_sphere_is_the_engines_background(tmp_path, empty_scene, mode):
    scene = empty_scene
    engine, record = _result(tmp_path)
    obj = background_sphere.import_background_sphere(tmp_path, record, scene.collection, mode)
    render_setup.apply(scene, mode)
    assert tuple(obj.location) == pytest.approx(tuple(CENTRE)) and tuple(obj.scale) == pytest.approx((RADIUS,) * 3)
    assert not obj.visible_shadow and not obj.visible_diffuse  # camera rays only
    cams = [_camera(CENTRE, CENTRE + [1.0, 0.4, 0.2], name="inside"),  # from the centre
            _camera(CENTRE + [-2.6, 0.5, 0.3], CENTRE + [1.0, -0.3, 0.0], name="near the shell"),  # across the dome
            _camera(CENTRE + [-3.3, -0.4, 0.2], CENTRE + [0.5, 0.2, 0.1], name="outside it")]  # the far side, through
    for i, cam in enumerate(cams):
        got = _cycles(scene, cam, tmp_path / f"{mode}_{i}.png")
        want = engine.image(cam).detach().numpy()
        err = np.abs(got - want)
        psnr = -10 * math.log10(float((err ** 2).mean()))
        print(f"\n{mode} {cam.name}: max |Cycles - engine| {err.max():.4f}, PSNR {psnr:.1f} dB")
        assert psnr > 40.0 and err.max() < 0.03, (cam.name, psnr, err.max())


def test_the_colour_mode_follows_the_scene_and_a_job_import_brings_the_sphere(tmp_path, empty_scene):
    import gsgs_blender
    from gsgs_blender import ops_result, ops_setup

    scene = empty_scene
    _, record = _result(tmp_path)
    gsgs_blender.register()  # the scene's GS-GS settings (colour mode)
    try:
        obj = background_sphere.import_background_sphere(tmp_path, record, scene.collection, "EXACT")
        image = bpy.data.images[obj["gsgs_image"]]
        assert image.colorspace_settings.name == "Non-Color"
        lines = ops_setup.set_up(scene, "LINEAR")
        assert image.colorspace_settings.name == "sRGB" and any("texture colour space" in line for line in lines)
        assert background_sphere.record_of(tmp_path) == record
        assert background_sphere.record_of(tmp_path / "nowhere") is None
        # a result's import replaces the earlier sphere; a result without one leaves none behind
        splats = bpy.data.objects.new("splats", None)
        scene.collection.objects.link(splats)
        ops_result.import_result_background(scene, tmp_path, splats)
        spheres = [o for o in scene.objects if "gsgs_background_sphere" in o]
        assert len(spheres) == 1 and any("background" in line for line in splats["gsgs_report"])
        (tmp_path / "other").mkdir()
        ops_result.import_result_background(scene, tmp_path / "other", splats)
        assert not [o for o in scene.objects if "gsgs_background_sphere" in o]
    finally:
        gsgs_blender.unregister()


def test_an_inward_shell_result_gives_the_scenes_cameras_its_near_plane(tmp_path, empty_scene):
    from gsgs_blender import ops_result

    scene = empty_scene
    cams = []
    for name, start in (("close", 0.05), ("far enough", 2.0)):
        cam = bpy.data.objects.new(name, bpy.data.cameras.new(name))
        cam.data.clip_start = start
        scene.collection.objects.link(cam)
        cams.append(cam)
    splats = bpy.data.objects.new("splats", None)
    scene.collection.objects.link(splats)

    def write(rig, near=0.26, scale=2.0):
        (tmp_path / "metrics.json").write_text(json.dumps({"plan": {
            "novel_view_near": near, "world_scale": scale, "effects": {"rig": {"value": rig}}}}))

    write("object orbit")  # other rigs draw with the renderer's default: nothing changes
    ops_result.fit_result_near(scene, tmp_path, splats)
    assert cams[0].data.clip_start == pytest.approx(0.05) and not splats.get("gsgs_report")
    write("inward shell", near=float("nan"))  # a broken record changes nothing either
    assert ops_result.result_near(tmp_path) is None
    write("inward shell")  # the near plane in world units (trainer units x world_scale), only raised
    ops_result.fit_result_near(scene, tmp_path, splats)
    assert cams[0].data.clip_start == pytest.approx(0.52) and cams[1].data.clip_start == pytest.approx(2.0)
    assert len(splats["gsgs_report"]) == 1 and "close clip start" in splats["gsgs_report"][0]
    assert ops_result.result_near(tmp_path / "nowhere") is None


def test_a_missing_texture_or_a_broken_record_is_refused_naming_the_file(tmp_path, empty_scene):
    from gsgs_engine import GsgsError

    _, record = _result(tmp_path)
    with pytest.raises(GsgsError, match="missing"):
        background_sphere.import_background_sphere(tmp_path, {**record, "file": "gone.png"},
                                                   empty_scene.collection)
    with pytest.raises(GsgsError, match="not a sphere"):
        background_sphere.import_background_sphere(tmp_path, {**record, "radius": -1.0}, empty_scene.collection)
    with pytest.raises(GsgsError, match="no valid centre"):
        background_sphere.import_background_sphere(tmp_path, {**record, "centre": None}, empty_scene.collection)
