"""Pseudo camera paths: a curve through the training cameras, pseudo poses sampled along it,
and their frusta drawn in the viewport.

A pseudo pose keeps the intrinsics of its nearest training camera and remembers that
camera's name ("nearest"), which the geometry-aware loss needs. Orientation either looks
at the scene centre or is slerped between the two nearest training cameras.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera, interpolate_cameras, look_at

PATH_NAME = "GS-GS Pseudo Path"


# -- pure geometry (numpy) -----------------------------------------------------------------------
def ring_order(positions: np.ndarray) -> np.ndarray:
    """Indices ordering points by angle around their centroid in their best-fit plane (a camera ring)."""
    p = np.asarray(positions, dtype=np.float64)
    if len(p) < 3:
        return np.arange(len(p))
    centred = p - p.mean(axis=0)
    _, _, vt = np.linalg.svd(centred, full_matrices=False)
    x, y = centred @ vt[0], centred @ vt[1]
    return np.argsort(np.arctan2(y, x), kind="stable")


def scene_centre(cameras: list[Camera], points: np.ndarray | None = None) -> np.ndarray:
    """The point closest (least squares) to every camera's optical axis; for near-parallel axes
    (a forward-facing capture) the median of the sparse points, else a point ahead of the cameras."""
    centres = np.stack([c.center for c in cameras])
    dirs = np.stack([c.R[2] for c in cameras])  # optical axes in world coordinates
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for o, d in zip(centres, dirs):
        P = np.eye(3) - np.outer(d, d)  # projector orthogonal to the axis
        A += P
        b += P @ o
    if len(cameras) >= 2 and np.linalg.cond(A) < 1e4:
        c = np.linalg.solve(A, b)
        # The intersection must lie in front of the cameras, or the rig is not inward-facing.
        if np.all(np.einsum("ij,ij->i", c - centres, dirs) > 0):
            return c
    if points is not None and len(points) > 0:
        return np.median(np.asarray(points, dtype=np.float64), axis=0)
    spread = max(float(np.linalg.norm(centres - centres.mean(0), axis=1).max()), 1.0)
    return centres.mean(0) + dirs.mean(0) * 2.0 * spread


def resample_polyline(points: np.ndarray, n: int, closed: bool) -> np.ndarray:
    """n points evenly spaced by arc length along a polyline (closed: around the loop, no repeat)."""
    p = np.asarray(points, dtype=np.float64)
    if len(p) == 0:
        raise GsgsError("the pseudo path has no points; draw or regenerate the path curve")
    if len(p) == 1 or n <= 0:
        return np.repeat(p[:1], max(n, 0), axis=0)
    if closed:
        p = np.concatenate([p, p[:1]])
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] <= 0:
        return np.repeat(p[:1], n, axis=0)
    targets = np.linspace(0.0, s[-1], n, endpoint=not closed) if n > 1 else np.array([0.0])
    return np.stack([np.interp(targets, s, p[:, k]) for k in range(3)], axis=1)


def pseudo_cameras(positions: np.ndarray, train: list[Camera], mode: str = "LOOK_AT",
                   centre: np.ndarray | None = None, prefix: str = "pseudo") -> list[Camera]:
    """A pseudo camera at each position: nearest training camera's intrinsics, oriented by `mode`."""
    if not train:
        raise GsgsError("no training cameras; import photos or use scene cameras first")
    centres = np.stack([c.center for c in train])
    up = -np.mean([c.R[1] for c in train], axis=0)  # OpenCV y points down in the image
    if np.linalg.norm(up) < 1e-6:
        up = np.array([0.0, 0.0, 1.0])
    out = []
    for i, pos in enumerate(np.asarray(positions, dtype=np.float64)):
        dist = np.linalg.norm(centres - pos, axis=1)
        order = np.argsort(dist)
        nearest = train[order[0]]
        if mode == "LOOK_AT":
            if centre is None:
                raise GsgsError("look-at orientation needs a scene centre")
            R, _ = look_at(pos, centre, up)
        elif mode == "SLERP":
            if len(train) == 1:
                R = nearest.R
            else:
                a, b = train[order[0]], train[order[1]]
                da, db = dist[order[0]], dist[order[1]]
                w = da / (da + db) if da + db > 0 else 0.0
                R = interpolate_cameras(a, b, w).R
        else:
            raise GsgsError(f"unknown pseudo orientation {mode!r}; use LOOK_AT or SLERP")
        cam = nearest.with_pose(R, -R @ pos, name=f"{prefix}_{i:03d}")
        out.append(replace(cam, extra={"nearest": nearest.name}))
    return out


def poses_to_json(cameras: list[Camera]) -> str:
    return json.dumps([{**c.to_dict(), "nearest": c.extra.get("nearest", "")} for c in cameras])


def poses_from_json(text: str) -> list[dict]:
    try:
        data = json.loads(text or "[]")
    except json.JSONDecodeError as exc:
        raise GsgsError(f"stored pseudo poses are not valid JSON ({exc}); sample the path again") from exc
    return data if isinstance(data, list) else []


def frustum_lines(cam: Camera, depth: float) -> np.ndarray:
    """World-space line segments (2K, 3) outlining a camera frustum of the given depth, with an
    'up' tick above the image's top edge so orientation reads at a glance."""
    W, H = cam.width, cam.height
    corners_px = np.array([[0, 0], [W, 0], [W, H], [0, H]], dtype=np.float64)
    rays = np.stack([(corners_px[:, 0] - cam.cx) / cam.fx, (corners_px[:, 1] - cam.cy) / cam.fy,
                     np.ones(4)], axis=1) * depth
    world = rays @ cam.R + cam.center  # R^T applied to row vectors
    c = cam.center
    top_mid = (world[0] + world[1]) / 2
    up_dir = world[0] - world[3]
    tick = top_mid + 0.25 * up_dir
    segs = [c, world[0], c, world[1], c, world[2], c, world[3],
            world[0], world[1], world[1], world[2], world[2], world[3], world[3], world[0],
            world[0], tick, tick, world[1]]
    return np.asarray(segs, dtype=np.float32)


# -- bpy ----------------------------------------------------------------------------------
def training_camera_objects(scene) -> list:
    coll = scene.gsgs.camera_collection
    if coll is None:
        return []
    return sorted((o for o in coll.all_objects if o.type == "CAMERA"), key=lambda o: o.name)


def make_path_curve(scene, positions: np.ndarray, closed: bool = True, kind: str = "BEZIER"):
    """A curve object through `positions` (Bezier with automatic handles: smooth and passing
    through every point; or POLY: straight segments). Replaces an earlier GS-GS path."""
    import bpy

    old = bpy.data.objects.get(PATH_NAME)
    if old is not None:
        bpy.data.objects.remove(old, do_unlink=True)
    curve = bpy.data.curves.new(PATH_NAME, "CURVE")
    curve.dimensions = "3D"
    curve.resolution_u = 16
    p = np.asarray(positions, dtype=np.float64)
    if kind == "BEZIER":
        spline = curve.splines.new("BEZIER")
        spline.bezier_points.add(len(p) - 1)
        spline.bezier_points.foreach_set("co", p.astype(np.float32).ravel())
        for bp in spline.bezier_points:
            bp.handle_left_type = bp.handle_right_type = "AUTO"
    elif kind == "POLY":
        spline = curve.splines.new("POLY")
        spline.points.add(len(p) - 1)
        spline.points.foreach_set("co", np.concatenate([p, np.ones((len(p), 1))], 1).astype(np.float32).ravel())
    else:
        raise GsgsError(f"unknown path kind {kind!r}; use BEZIER or POLY")
    spline.use_cyclic_u = closed
    obj = bpy.data.objects.new(PATH_NAME, curve)
    scene.collection.objects.link(obj)
    scene.gsgs.pseudo_curve = obj
    return obj


def curve_polyline(obj, depsgraph) -> tuple[np.ndarray, bool]:
    """World-space points of the evaluated curve (what the user sees) and whether it is closed."""
    if obj is None or obj.type != "CURVE":
        raise GsgsError("the pseudo path must be a curve object; create one with 'Path Through Cameras'")
    if len(obj.data.splines) == 0:
        raise GsgsError(f"curve {obj.name!r} has no splines; draw a path or regenerate it")
    closed = bool(obj.data.splines[0].use_cyclic_u)
    evaluated = obj.evaluated_get(depsgraph)
    mesh = evaluated.to_mesh()
    try:
        co = np.empty(len(mesh.vertices) * 3, np.float32)
        mesh.vertices.foreach_get("co", co)
        co = co.reshape(-1, 3).astype(np.float64)
        # to_mesh keeps the first spline's points in order; a cyclic one does not repeat its start.
        mw = np.asarray(obj.matrix_world)
        world = co @ mw[:3, :3].T + mw[:3, 3]
    finally:
        evaluated.to_mesh_clear()
    if closed and len(world) > 2 and np.allclose(world[0], world[-1]):
        world = world[:-1]
    return world, closed


def sample_pseudo_poses(context, count: int | None = None, mode: str | None = None) -> list[Camera]:
    """Sample the scene's path curve into pseudo cameras and store them on the scene."""
    from . import camera_convert

    scene = context.scene
    settings = scene.gsgs
    cams = [camera_convert.camera_from_object(o, scene) for o in training_camera_objects(scene)]
    if not cams:
        raise GsgsError("no training cameras: import photos or mark scene cameras first")
    polyline, closed = curve_polyline(settings.pseudo_curve, context.evaluated_depsgraph_get())
    positions = resample_polyline(polyline, count or settings.pseudo_count, closed)
    centre = scene_centre(cams, sparse_points_world(settings))
    result = pseudo_cameras(positions, cams, mode or settings.pseudo_orientation, centre)
    settings.pseudo_poses = poses_to_json(result)
    invalidate_draw_cache()
    return result


def sparse_points_world(settings) -> np.ndarray | None:
    """The Sparse Points object's vertices in world coordinates (N x 3; those of the training cameras), or None."""
    obj = settings.points_object
    if obj is None or obj.type != "MESH":
        return None
    co = np.empty(len(obj.data.vertices) * 3, np.float32)
    obj.data.vertices.foreach_get("co", co)
    mw = np.asarray(obj.matrix_world)
    return co.reshape(-1, 3) @ mw[:3, :3].T + mw[:3, 3]


# -- viewport drawing ---------------------------------------------------------------------------------
_HANDLE = None
_CACHE: dict = {"key": None, "batch": None}


def invalidate_draw_cache() -> None:
    _CACHE["key"] = None
    _CACHE["batch"] = None


def _draw() -> None:
    import bpy
    import gpu
    from gpu_extras.batch import batch_for_shader

    scene = bpy.context.scene
    settings = getattr(scene, "gsgs", None)
    if settings is None or not settings.show_frusta:
        return
    text = settings.pseudo_poses
    if _CACHE["key"] != text:
        try:
            cams = [Camera.from_dict(p, source="pseudo pose") for p in poses_from_json(text)]
        except GsgsError:  # a hand-edited property: draw nothing rather than fail every redraw
            cams = []
        if not cams:
            _CACHE.update(key=text, batch=None)
            return
        centres = np.stack([c.center for c in cams])
        size = 0.1 * max(float(np.linalg.norm(centres - centres.mean(0), axis=1).max()), 0.1)
        coords = np.concatenate([frustum_lines(c, size) for c in cams])
        shader = gpu.shader.from_builtin("UNIFORM_COLOR")
        _CACHE.update(key=text, batch=batch_for_shader(shader, "LINES", {"pos": coords.tolist()}), shader=shader)
    if _CACHE["batch"] is None:
        return
    shader = _CACHE["shader"]
    gpu.state.depth_test_set("LESS_EQUAL")  # frusta hide behind the splats, like real objects
    shader.bind()
    shader.uniform_float("color", (1.0, 0.55, 0.1, 1.0))
    _CACHE["batch"].draw(shader)
    gpu.state.depth_test_set("NONE")


def register_drawing() -> None:
    global _HANDLE
    import bpy

    if bpy.app.background or _HANDLE is not None:  # no GPU context without a window
        return
    _HANDLE = bpy.types.SpaceView3D.draw_handler_add(_draw, (), "WINDOW", "POST_VIEW")


def unregister_drawing() -> None:
    global _HANDLE
    import bpy

    if _HANDLE is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_HANDLE, "WINDOW")
        _HANDLE = None
    invalidate_draw_cache()
