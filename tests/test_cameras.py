"""Camera conventions: round trips, hand-checked values, and one point through every convention."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from gsgs_engine import GsgsError
from gsgs_engine.cameras import (
    Camera,
    blender_from_camera,
    camera_from_blender,
    camera_from_colmap,
    camera_from_nerf,
    cameras_from_llff,
    colmap_from_camera,
    distort_normalized,
    interpolate_cameras,
    llff_from_cameras,
    look_at,
    nerf_c2w_from_camera,
    quat_to_rotmat,
    rotmat_to_quat,
    slerp,
    undistort_normalized,
)


def random_rotations(n: int, seed: int = 0) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return quat_to_rotmat(q)


def random_camera(seed: int, fx=500.0, fy=None, cx=None, cy=None, width=640, height=480) -> Camera:
    rng = np.random.default_rng(seed)
    R = random_rotations(1, seed)[0]
    return Camera(R=R, t=rng.normal(size=3), fx=fx, fy=fx if fy is None else fy,
                  cx=width / 2 if cx is None else cx, cy=height / 2 if cy is None else cy,
                  width=width, height=height, name=f"cam{seed}")


def assert_same_camera(a: Camera, b: Camera, atol=1e-7) -> None:
    np.testing.assert_allclose(a.R, b.R, atol=atol)
    np.testing.assert_allclose(a.t, b.t, atol=atol)
    np.testing.assert_allclose([a.fx, a.fy, a.cx, a.cy], [b.fx, b.fy, b.cx, b.cy], rtol=1e-9, atol=atol)
    assert (a.width, a.height) == (b.width, b.height)


# -- rotations ------------------------------------------------------------------------------
def test_quaternion_round_trip_and_matches_rotation():
    R = random_rotations(200, seed=1)
    assert np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    q = rotmat_to_quat(R)
    assert np.all(q[:, 0] >= 0)
    np.testing.assert_allclose(quat_to_rotmat(q), R, atol=1e-12)
    # 90 degrees about z by hand: (w, x, y, z) = (cos 45, 0, 0, sin 45) maps x -> y
    Rz = quat_to_rotmat([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)])
    np.testing.assert_allclose(Rz @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_rotmat_to_quat_near_half_turns():
    # w ~ 0: the branch that divides by w would blow up here
    for axis in np.eye(3):
        R = quat_to_rotmat(np.r_[1e-9, axis])
        np.testing.assert_allclose(quat_to_rotmat(rotmat_to_quat(R)), R, atol=1e-12)


def test_slerp_endpoints_halfway_and_short_path():
    q0 = np.array([1.0, 0, 0, 0])
    q1 = np.array([np.cos(0.6), np.sin(0.6), 0, 0])  # 1.2 rad about x
    np.testing.assert_allclose(slerp(q0, q1, 0.0), q0, atol=1e-12)
    np.testing.assert_allclose(slerp(q0, q1, 1.0), q1, atol=1e-12)
    ts = np.linspace(0, 1, 5)
    qs = slerp(q0, q1, ts)
    angles = 2 * np.arccos(np.clip(qs[:, 0], -1, 1))
    np.testing.assert_allclose(angles, 1.2 * ts, atol=1e-12)  # constant angular speed
    # -q1 is the same rotation; slerp must still take the 1.2 rad path, not the 2pi - 1.2 one
    np.testing.assert_allclose(quat_to_rotmat(slerp(q0, -q1, 0.5)), quat_to_rotmat(slerp(q0, q1, 0.5)), atol=1e-12)
    np.testing.assert_allclose(slerp(q0, q0, 0.3), q0, atol=1e-12)


def test_interpolate_cameras_and_look_at():
    R, t = look_at(eye=[4, 0, 0], target=[0, 0, 0], up=[0, 0, 1])
    a = Camera(R=R, t=t, fx=100, fy=100, cx=50, cy=50, width=100, height=100, name="a")
    uv, z = a.project(np.array([[0.0, 0, 0], [0, 0, 1]]))
    np.testing.assert_allclose(uv[0], [50, 50], atol=1e-9)
    assert z[0] == pytest.approx(4.0)
    assert uv[1, 1] < 50  # world up is image up (smaller v)
    R2, t2 = look_at(eye=[0, 4, 0], target=[0, 0, 0], up=[0, 0, 1])
    b = a.with_pose(R2, t2, name="b")
    assert_same_camera(interpolate_cameras(a, b, 0.0), a)
    assert_same_camera(interpolate_cameras(a, b, 1.0), b)
    mid = interpolate_cameras(a, b, 0.5)
    np.testing.assert_allclose(mid.center, [2, 2, 0], atol=1e-12)
    mid.validate()


# -- Blender -------------------------------------------------------------------------------
def test_blender_hand_checked_intrinsics():
    m = np.eye(4)  # Blender camera at the origin looking down -Z
    cam = camera_from_blender(m, lens=50, sensor_width=36, resolution_x=1920, resolution_y=1080,
                              shift_x=0.1, shift_y=0.05)
    assert cam.fx == pytest.approx(50 * 1920 / 36)
    assert cam.fy == pytest.approx(cam.fx)
    assert cam.cx == pytest.approx(960 - 0.1 * 1920)  # +shift_x moves the frame right: content left
    assert cam.cy == pytest.approx(540 + 0.05 * 1920)  # shift is in units of the fitted (larger) side
    uv, z = cam.project(np.array([[0.0, 0.0, -3.0]]))
    np.testing.assert_allclose(uv[0], [cam.cx, cam.cy])
    assert z[0] == pytest.approx(3.0)
    # portrait + AUTO fits the height but still uses sensor_width; percentage truncates like Blender
    p = camera_from_blender(m, lens=50, sensor_width=36, sensor_height=24, resolution_x=1081, resolution_y=1920,
                            resolution_percentage=50)
    assert (p.width, p.height) == (540, 960)
    assert p.fy == pytest.approx(50 * 960 / 36)
    # VERTICAL uses sensor_height along the height
    v = camera_from_blender(m, lens=50, sensor_width=36, sensor_height=24, sensor_fit="VERTICAL",
                            resolution_x=1920, resolution_y=1080)
    assert v.fy == pytest.approx(50 * 1080 / 24)
    # non-square pixels: a pixel twice as tall as wide has half as many rows per unit height
    a = camera_from_blender(m, lens=50, resolution_x=1000, resolution_y=1000, pixel_aspect_x=1, pixel_aspect_y=2)
    assert a.fx == pytest.approx(2 * a.fy)


@pytest.mark.parametrize("sensor_fit", ["AUTO", "HORIZONTAL", "VERTICAL"])
@pytest.mark.parametrize("seed", range(4))
def test_blender_round_trip(sensor_fit, seed):
    rng = np.random.default_rng(seed)
    width, height = [(640, 480), (480, 640), (333, 333), (1000, 250)][seed]
    fx = rng.uniform(200, 900)
    fy = fx * [1.0, 1.3, 0.7, 1.0][seed]  # square, tall and wide pixels
    cam = random_camera(seed, fx=fx, fy=fy, cx=width / 2 + rng.uniform(-40, 40), cy=height / 2 + rng.uniform(-40, 40),
                        width=width, height=height)
    d = blender_from_camera(cam, sensor_fit=sensor_fit)
    assert min(d["pixel_aspect_x"], d["pixel_aspect_y"]) == pytest.approx(1.0)
    assert d["pixel_aspect_y"] / d["pixel_aspect_x"] == pytest.approx(fx / fy)
    back = camera_from_blender(**d)
    assert_same_camera(back, cam, atol=1e-9)
    assert back.name == cam.name


def test_blender_ignores_object_scale_and_rejects_bad_input():
    cam = random_camera(3)
    d = blender_from_camera(cam)
    m = np.array(d["matrix_world"])
    m[:3, :3] *= 2.5  # a scaled camera object renders the same picture
    assert_same_camera(camera_from_blender(**{**d, "matrix_world": m}), cam, atol=1e-9)
    with pytest.raises(GsgsError, match="sensor_fit"):
        camera_from_blender(**{**d, "sensor_fit": "DIAGONAL"})
    m[0, 0] = np.nan
    with pytest.raises(GsgsError, match="NaN"):
        camera_from_blender(**{**d, "matrix_world": m})


@pytest.mark.blender
def test_blender_projection_matches_bpy():
    bpy = pytest.importorskip("bpy")
    from mathutils import Euler, Matrix

    scene = bpy.context.scene
    data = bpy.data.cameras.new("gsgs_test_cam")
    obj = bpy.data.objects.new("gsgs_test_cam", data)
    scene.collection.objects.link(obj)
    rng = np.random.default_rng(7)
    try:
        for fit, rx, ry, ax, ay, sx, sy in [("AUTO", 640, 480, 1, 1, 0.1, -0.2), ("AUTO", 480, 640, 1, 1, 0.1, 0.2),
                                            ("HORIZONTAL", 480, 640, 1, 2, 0.05, 0.1),
                                            ("VERTICAL", 640, 480, 2, 1, -0.1, 0.3), ("AUTO", 400, 380, 1, 1.3, 0.2, 0.1)]:
            data.sensor_fit, data.lens, data.sensor_width, data.sensor_height = fit, 35.0, 36.0, 20.0
            data.shift_x, data.shift_y = sx, sy
            r = scene.render
            r.resolution_x, r.resolution_y, r.resolution_percentage = rx, ry, 50
            r.pixel_aspect_x, r.pixel_aspect_y = ax, ay
            obj.matrix_world = Matrix.Translation((1, 2, 3)) @ Euler((1.1, 0.2, 0.5)).to_matrix().to_4x4()
            bpy.context.view_layer.update()
            w, h = rx // 2, ry // 2
            P = np.array(obj.calc_matrix_camera(bpy.context.evaluated_depsgraph_get(), x=w, y=h, scale_x=ax, scale_y=ay))
            M = np.array(obj.matrix_world)
            pts = M[:3, 3] - 5 * M[:3, 2] + rng.normal(size=(6, 3))  # in front: Blender looks down -Z
            clip = np.c_[pts, np.ones(len(pts))] @ (P @ np.linalg.inv(M)).T
            ndc = clip[:, :2] / clip[:, 3:]
            uv_blender = np.stack([(ndc[:, 0] + 1) / 2 * w, (1 - ndc[:, 1]) / 2 * h], axis=1)
            cam = camera_from_blender(M, data.lens, data.sensor_width, data.sensor_height, fit, sx, sy, rx, ry, 50, ax, ay)
            uv, z = cam.project(pts)
            assert np.all(z > 0)
            np.testing.assert_allclose(uv, uv_blender, atol=1e-3)  # bpy matrices are float32
    finally:
        bpy.data.objects.remove(obj)
        bpy.data.cameras.remove(data)


# -- NeRF ------------------------------------------------------------------------------------
def test_nerf_round_trip_and_axes():
    cam = random_camera(5, fx=320, fy=300, cx=310, cy=250)
    c2w = nerf_c2w_from_camera(cam)
    back = camera_from_nerf(c2w, cam.width, cam.height, fl_x=cam.fx, fl_y=cam.fy, cx=cam.cx, cy=cam.cy)
    assert_same_camera(back, cam, atol=1e-9)
    # OpenGL camera at z=4 looking back at the origin (identity rotation): -z is forward, +y is up
    c2w = np.eye(4)
    c2w[2, 3] = 4.0
    cam = camera_from_nerf(c2w, 200, 100, camera_angle_x=0.69)
    assert cam.fx == pytest.approx(100 / np.tan(0.345))
    uv, z = cam.project(np.array([[0.0, 0, 0], [0, 0.5, 0], [0.5, 0, 0]]))
    np.testing.assert_allclose(uv[0], [100, 50])
    assert z[0] == pytest.approx(4.0)
    assert uv[1, 1] < 50 and uv[2, 0] > 100  # world +y up in the image, +x right
    cam_y = camera_from_nerf(c2w, 200, 100, camera_angle_x=0.69, camera_angle_y=0.3)
    assert cam_y.fy == pytest.approx(50 / np.tan(0.15))
    with pytest.raises(GsgsError, match="focal"):
        camera_from_nerf(c2w, 200, 100)


# -- LLFF -------------------------------------------------------------------------------------
def test_llff_round_trip_rescale_and_column_order():
    cams = [random_camera(s, fx=3000, width=4032, height=3024) for s in range(3)]
    cams = [replace(c, near=1.5, far=30.0) for c in cams]
    arr = llff_from_cameras(cams)
    assert arr.shape == (3, 17)
    back = cameras_from_llff(arr, (4032, 3024))
    for a, b in zip(cams, back):
        assert_same_camera(a, b, atol=1e-9)
        assert (b.near, b.far) == (1.5, 30.0)
    small = cameras_from_llff(arr, (504, 378))[0]
    assert small.fx == pytest.approx(3000 / 8) and small.fy == pytest.approx(3000 / 8)
    assert (small.cx, small.cy) == (252.0, 189.0)
    # A hand-written row: columns are (down, right, back) in world coordinates. This camera sits at
    # z = -5 looking along +z, with world +x to its right and world +y down in the image.
    m = np.zeros((3, 5))
    m[:, 0] = [0, 1, 0]  # down
    m[:, 1] = [1, 0, 0]  # right
    m[:, 2] = [0, 0, -1]  # back
    m[:, 3] = [0, 0, -5]
    m[:, 4] = [100, 200, 150]  # h, w, f of the original photos
    row = np.r_[m.reshape(-1), 1.0, 10.0]
    cam = cameras_from_llff(row[None], (200, 100))[0]
    uv, z = cam.project(np.array([[0.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]]))
    np.testing.assert_allclose(uv, [[100, 50], [100 + 150 / 5, 50], [100, 50 + 150 / 5]])
    assert z[0] == pytest.approx(5.0)
    assert (cam.near, cam.far) == (1.0, 10.0)


def test_llff_rejects_bad_rows():
    arr = llff_from_cameras([random_camera(0, width=400, height=300)], near=1, far=2)
    with pytest.raises(GsgsError, match="aspect"):
        cameras_from_llff(arr, (400, 400))
    bad = arr.copy()
    bad[0, 3] = np.nan
    with pytest.raises(GsgsError, match="NaN"):
        cameras_from_llff(bad, (400, 300))
    with pytest.raises(GsgsError, match=r"\(N, 17\)"):
        cameras_from_llff(arr[:, :15], (400, 300))


# -- COLMAP -----------------------------------------------------------------------------------
def test_colmap_round_trip_and_models():
    cam = random_camera(9, fx=410, fy=400, cx=300, cy=260)
    q, t, model, params = colmap_from_camera(cam)
    back, und = camera_from_colmap(q, t, model, params, cam.width, cam.height)
    assert und is None
    assert_same_camera(back, cam, atol=1e-9)
    simple, und = camera_from_colmap(q, t, "SIMPLE_PINHOLE", [410, 300, 260], cam.width, cam.height)
    assert und is None and simple.fx == simple.fy == 410
    # a distortion model whose coefficients are all zero is a pinhole camera
    plain, und = camera_from_colmap(q, t, "OPENCV", [410, 400, 300, 260, 0, 0, 0, 0], cam.width, cam.height)
    assert und is None
    assert_same_camera(plain, cam, atol=1e-9)
    with pytest.raises(GsgsError, match="OPENCV_FISHEYE.*image_undistorter"):
        camera_from_colmap(q, t, "OPENCV_FISHEYE", [1, 1, 1, 1, 0, 0, 0, 0], 10, 10)
    with pytest.raises(GsgsError, match="parameters"):
        camera_from_colmap(q, t, "PINHOLE", [1, 2, 3], 10, 10)
    with pytest.raises(GsgsError, match="NaN"):
        camera_from_colmap([np.nan, 0, 0, 0], t, "PINHOLE", params, 10, 10)


def test_undistort_inverts_distort():
    coeffs = {"k1": -0.2, "k2": 0.05, "p1": 0.001, "p2": -0.002}
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-0.6, 0.6, size=(2, 100))
    xd, yd = distort_normalized(x, y, coeffs)
    xu, yu = undistort_normalized(xd, yd, coeffs)
    np.testing.assert_allclose(xu, x, atol=1e-10)
    np.testing.assert_allclose(yu, y, atol=1e-10)


@pytest.mark.parametrize("model,params", [
    ("SIMPLE_RADIAL", [300, 161, 119, -0.12]),
    ("RADIAL", [300, 160, 120, 0.08, 0.01]),
    ("OPENCV", [300, 290, 158, 122, -0.1, 0.02, 0.002, -0.001]),
    ("FULL_OPENCV", [300, 290, 158, 122, -0.1, 0.02, 0.002, -0.001, 0.001, 0.01, 0.0, 0.0]),
])
def test_colmap_distorted_models_give_consistent_undistortion(model, params):
    R, t = look_at([0, -3, 0.5], [0, 0, 0])
    target, und = camera_from_colmap(rotmat_to_quat(R), t, model, params, 320, 240, name="d")
    assert und is not None and (target.width, target.height) == (320, 240)
    map_x, map_y = und.maps()
    assert map_x.shape == (240, 320) and map_x.dtype == np.float32
    # no blank border: every target pixel samples inside the photo (OpenCV pixel centres 0..W-1)
    assert map_x.min() >= -0.5 - 1e-3 and map_x.max() <= 319.5 + 1e-3
    assert map_y.min() >= -0.5 - 1e-3 and map_y.max() <= 239.5 + 1e-3
    # ... and it touches the photo's border (no needless zoom)
    assert min(map_x.min() + 0.5, 319.5 - map_x.max(), map_y.min() + 0.5, 239.5 - map_y.max()) < 1.0
    # A 3D point: the pinhole target projects it to p; the map at p holds where the distorted
    # camera saw it (distortion applied to its normalized coordinates).
    pts = np.random.default_rng(1).uniform(-0.5, 0.5, size=(20, 3))
    uv, _ = target.project(pts)
    pc = und.source.to_camera(pts)
    xd, yd = distort_normalized(pc[:, 0] / pc[:, 2], pc[:, 1] / pc[:, 2], und.coeffs)
    expected = np.stack([und.source.fx * xd + und.source.cx - 0.5, und.source.fy * yd + und.source.cy - 0.5], 1)
    inside = (uv[:, 0] > 1) & (uv[:, 0] < 318) & (uv[:, 1] > 1) & (uv[:, 1] < 238)
    assert inside.sum() >= 10
    for (u, v), e in zip(uv[inside], expected[inside]):
        # bilinear lookup of the map at continuous (u, v)
        fu, fv = u - 0.5, v - 0.5
        i0, j0 = int(np.floor(fv)), int(np.floor(fu))
        a, b = fv - i0, fu - j0
        look = lambda m: ((1 - a) * (1 - b) * m[i0, j0] + (1 - a) * b * m[i0, j0 + 1]  # noqa: E731
                          + a * (1 - b) * m[i0 + 1, j0] + a * b * m[i0 + 1, j0 + 1])
        np.testing.assert_allclose([look(map_x), look(map_y)], e, atol=0.02)


# -- every convention agrees ----------------------------------------------------------------------
def test_one_point_lands_on_one_pixel_through_every_convention():
    R, t = look_at(eye=[2.0, -3.0, 1.5], target=[0.1, 0.2, 0.0], up=[0, 0, 1])
    cam = Camera(R=R, t=t, fx=420.0, fy=420.0, cx=320.0, cy=240.0, width=640, height=480, name="x",
                 near=0.5, far=20.0)
    point = np.array([[0.3, -0.2, 0.4]])
    uv_ref, z_ref = cam.project(point)
    assert 0 < uv_ref[0, 0] < 640 and 0 < uv_ref[0, 1] < 480 and z_ref[0] > 0

    via = {
        "blender": camera_from_blender(**blender_from_camera(cam)),
        "blender-vertical": camera_from_blender(**blender_from_camera(cam, sensor_fit="VERTICAL", sensor_height=24.0)),
        "nerf": camera_from_nerf(nerf_c2w_from_camera(cam), 640, 480, camera_angle_x=cam.fov_x),
        "llff": cameras_from_llff(llff_from_cameras([cam]), (640, 480))[0],
        "colmap": camera_from_colmap(*colmap_from_camera(cam), 640, 480)[0],
        "dict": Camera.from_dict(cam.to_dict()),
    }
    for name, other in via.items():
        uv, z = other.project(point)
        np.testing.assert_allclose(uv, uv_ref, atol=1e-6, err_msg=name)
        np.testing.assert_allclose(z, z_ref, atol=1e-9, err_msg=name)
    # the Blender camera's own axes: the point in Blender camera space has negative z, y up
    m = np.array(blender_from_camera(cam)["matrix_world"])
    p_blender = np.linalg.inv(m) @ np.r_[point[0], 1.0]
    assert p_blender[2] == pytest.approx(-z_ref[0])
    assert np.sign(p_blender[1]) == -np.sign(uv_ref[0, 1] - cam.cy)


@pytest.mark.parametrize("model,params", [
    ("SIMPLE_RADIAL", [300, 161, 119, -0.12]),
    ("RADIAL", [300, 160, 120, 0.08, 0.01]),
    ("OPENCV", [300, 290, 158, 122, -0.1, 0.02, 0.002, -0.001]),
    ("FULL_OPENCV", [300, 290, 158, 122, -0.1, 0.02, 0.002, -0.001, 0.001, 0.01, 0.002, 0.003]),
])
def test_distortion_matches_pycolmap(model, params):
    pycolmap = pytest.importorskip("pycolmap")
    ref = pycolmap.Camera(model=model, width=320, height=240, params=params)
    target, und = camera_from_colmap([1, 0, 0, 0], [0, 0, 0], model, params, 320, 240)
    pc = np.c_[np.random.default_rng(2).uniform(-0.5, 0.5, size=(50, 2)), np.ones(50)]
    xd, yd = distort_normalized(pc[:, 0], pc[:, 1], und.coeffs)
    ours = np.stack([und.source.fx * xd + und.source.cx, und.source.fy * yd + und.source.cy], axis=1)
    np.testing.assert_allclose(ours, ref.img_from_cam(pc), atol=1e-9)


@pytest.mark.parametrize("u,v", [((0, 0, 1), (0, 1, 0)), ((1, 2, 3), (-3, 0.5, 1)), ((0, 0, 1), (0, 0, 1)),
                                 ((0, 0, 1), (0, 0, -1)), ((1, 0, 0), (-1, 1e-14, 0))])
def test_rotation_between_is_a_rotation_taking_u_to_v(u, v):
    from gsgs_engine.cameras import rotation_between

    Q = rotation_between(np.array(u, float), np.array(v, float))
    assert np.allclose(Q @ Q.T, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(Q), 1.0)
    assert np.allclose(Q @ (np.array(u) / np.linalg.norm(u)), np.array(v) / np.linalg.norm(v), atol=1e-9)
