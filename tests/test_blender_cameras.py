"""Blender camera <-> engine Camera: round trips and pixel-exact projection against Blender's own."""

from __future__ import annotations

import numpy as np
import pytest

from gsgs_blender import camera_convert as cc
from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera


def _rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _random_camera(rng, width=320, height=200, fy_ratio=1.0) -> Camera:
    fx = rng.uniform(150, 600)
    return Camera(R=_rotation(rng), t=rng.normal(size=3) * 2, fx=fx, fy=fx * fy_ratio,
                  cx=width / 2 + rng.uniform(-40, 40), cy=height / 2 + rng.uniform(-30, 30),
                  width=width, height=height, name="c")


def test_bad_fit_is_a_clear_error():
    with pytest.raises(GsgsError, match="sensor_fit"):
        cc.camera_from_blender(np.eye(4), 50.0, sensor_fit="DIAGONAL")


# -- with the real bpy module ---------------------------------------------------------------

@pytest.fixture()
def empty_scene():
    global bpy
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene
    bpy.ops.wm.read_factory_settings(use_empty=True)


@pytest.mark.blender
@pytest.mark.parametrize("fy_ratio", [1.0, 1.25, 0.8])
def test_engine_blender_engine_round_trip(empty_scene, fy_ratio):
    rng = np.random.default_rng(7)
    cam = _random_camera(rng, 320, 200, fy_ratio)
    obj = cc.new_camera_object(cam, empty_scene.collection, empty_scene)
    back = cc.camera_from_object(obj, empty_scene)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-6)
    np.testing.assert_allclose(back.t, cam.t, atol=1e-6)
    np.testing.assert_allclose([back.fx, back.fy, back.cx, back.cy], [cam.fx, cam.fy, cam.cx, cam.cy], atol=1e-6 * cam.fx)
    assert (back.width, back.height) == (320, 200)
    # The scene frame is untouched unless asked; with set_scene_frame it matches the camera.
    cc.apply_camera_to_object(cam, obj, empty_scene, set_scene_frame=True)
    assert (empty_scene.render.resolution_x, empty_scene.render.resolution_y) == (320, 200)
    del obj[cc.PROP_WIDTH], obj[cc.PROP_HEIGHT], obj[cc.PROP_ASPECT]  # now read from the scene
    again = cc.camera_from_object(obj, empty_scene)
    np.testing.assert_allclose([again.fx, again.fy, again.cx, again.cy], [cam.fx, cam.fy, cam.cx, cam.cy],
                               atol=1e-6 * cam.fx)


@pytest.mark.blender
def test_object_scale_does_not_change_the_camera(empty_scene):
    rng = np.random.default_rng(3)
    cam = _random_camera(rng)
    obj = cc.new_camera_object(cam, empty_scene.collection, empty_scene)
    obj.scale = (2.0, 2.0, 2.0)
    bpy.context.view_layer.update()
    back = cc.camera_from_object(obj, empty_scene)
    np.testing.assert_allclose(back.R, cam.R, atol=1e-6)
    np.testing.assert_allclose(back.center, cam.center, atol=1e-6)


@pytest.mark.blender
@pytest.mark.parametrize("fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
@pytest.mark.parametrize("res,aspect", [((320, 200), (1.0, 1.0)), ((200, 330), (1.0, 1.0)),
                                        ((320, 200), (1.5, 1.0)), ((240, 300), (1.0, 1.3))])
def test_same_pixel_as_blender_projection(empty_scene, fit, res, aspect):
    from bpy_extras.object_utils import world_to_camera_view
    from mathutils import Euler, Vector

    scene = empty_scene
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x, scene.render.pixel_aspect_y = aspect
    data = bpy.data.cameras.new("cam")
    data.lens, data.sensor_width, data.sensor_height, data.sensor_fit = 42.0, 36.0, 20.0, fit
    data.shift_x, data.shift_y = 0.13, -0.21
    obj = bpy.data.objects.new("cam", data)
    scene.collection.objects.link(obj)
    obj.location = (1.0, -6.0, 2.0)
    obj.rotation_euler = Euler((1.3, 0.1, 0.2), "XYZ")
    bpy.context.view_layer.update()

    cam = cc.camera_from_object(obj, scene)
    rng = np.random.default_rng(1)
    forward = -np.asarray(obj.matrix_world)[:3, 2]
    pts = np.asarray(obj.location) + forward * rng.uniform(3, 8, size=(20, 1)) + rng.normal(size=(20, 3)) * 0.7
    uv, z = cam.project(pts)
    W, H = res
    for p, (u, v), depth in zip(pts, uv, z):
        ndc = world_to_camera_view(scene, obj, Vector(p))
        assert ndc.z == pytest.approx(depth, rel=1e-5)
        # Blender's NDC: (0, 0) bottom-left, (1, 1) top-right of the frame.
        assert ndc.x * W == pytest.approx(u, abs=2e-3)
        assert (1.0 - ndc.y) * H == pytest.approx(v, abs=2e-3)


@pytest.mark.blender
def test_non_camera_object_is_rejected(empty_scene):
    obj = bpy.data.objects.new("empty", None)
    empty_scene.collection.objects.link(obj)
    with pytest.raises(GsgsError, match="not a camera"):
        cc.camera_from_object(obj, empty_scene)
