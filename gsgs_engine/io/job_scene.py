"""The scene of a job folder: job.json's "data" names a scene folder or lists cameras inline.

    "data": {"source": "/path/to/scene", "format": "auto", "train_split": null,
             "train_ids": [0, 5, 9], "train_views": null, "resolution_scale": 1.0,
             "background": [1, 1, 1], "frames": "0-9"}
or
    "data": {"cameras": [{<Camera.to_dict()>, "image": "images/a.png", "split": "train"}, ...],
             "background": [1, 1, 1], "near": 0.1, "far": 100.0, "points": "points.ply"}

Relative paths are relative to the job folder ("path" is accepted for "source"). Arguments
given to load_scene override these values; a missing "split" means "train".
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.io.images import check_same_size, image_info, make_view
from gsgs_engine.io.scene import Scene
from gsgs_engine.io.selection import check_background, select_train
from gsgs_engine.job import Job


@dataclass
class SceneSource:
    """A job whose data names a scene folder: load_scene(path, **arguments) loads it."""

    path: Path
    arguments: dict


def load_job_scene(path, train_split=None, train_views=None, train_ids=None, resolution_scale=None,
                   background=None, frames=None) -> Scene | SceneSource:
    """The job's inline scene, or the scene folder it names (a SceneSource, which load_scene loads)."""
    path = Path(path)
    job = Job.open(path.parent if path.name == "job.json" else path)
    data = job.spec.get("data")
    where = f"{job.spec_path} data"
    if not isinstance(data, dict):
        raise GsgsError(f"{where}: expected an object naming the scene (\"source\") or listing \"cameras\"")
    pick = lambda arg, key: data.get(key) if arg is None else arg  # noqa: E731
    train_split, train_views, train_ids = pick(train_split, "train_split"), pick(train_views, "train_views"), \
        pick(train_ids, "train_ids")
    frames = pick(frames, "frames")
    scale = float(pick(resolution_scale, "resolution_scale") or 1.0)
    bg_value = pick(background, "background")
    bg = check_background((1.0, 1.0, 1.0) if bg_value is None else bg_value)
    source = data.get("source", data.get("path"))
    if "cameras" in data:
        if frames is not None:
            raise GsgsError(f"{where}: \"frames\" picks frames of a scene folder with time; an inline camera list "
                            "has no frames to pick, remove it")
        scene = _inline_scene(job, data, scale, bg)
        return select_train(scene, train_split=train_split, train_ids=train_ids, train_views=train_views)
    if not source:
        raise GsgsError(f"{where}: names no scene; add \"source\" (a scene folder) or a \"cameras\" list")
    scene_path = _resolve(job.root, source)
    if scene_path.resolve() == job.root.resolve():
        raise GsgsError(f"{where}.source points at the job folder itself; name the scene folder instead")
    return SceneSource(scene_path, {"format": data.get("format", "auto"), "train_split": train_split,
                                    "train_views": train_views, "train_ids": train_ids, "resolution_scale": scale,
                                    "background": bg, "frames": frames})


def _resolve(root: Path, p) -> Path:
    p = Path(str(p)).expanduser()
    return p if p.is_absolute() else root / p


def _inline_scene(job: Job, data: dict, scale: float, bg: np.ndarray) -> Scene:
    entries = data["cameras"]
    where = f"{job.spec_path} data.cameras"
    if not isinstance(entries, list) or not entries:
        raise GsgsError(f"{where}: expected a non-empty list of cameras (Camera.to_dict() plus \"image\")")
    views, splits, sizes, has_alpha = [], {}, {}, False
    for i, entry in enumerate(entries):
        label = f"{where}[{i}]"
        if not isinstance(entry, dict) or not entry.get("image"):
            raise GsgsError(f"{label}: every camera needs an \"image\" path")
        cam = Camera.from_dict(entry, source=label)
        image_path = _resolve(job.root, entry["image"])
        info = image_info(image_path)
        if (info.width, info.height) != (cam.width, cam.height):
            raise GsgsError(f"{image_path}: image is {info.width}x{info.height} but {label} says "
                            f"{cam.width}x{cam.height}; fix the camera's width/height or the image")
        has_alpha |= info.channels in (2, 4)
        split = str(entry.get("split", "train"))
        splits.setdefault(split, []).append(len(views))
        sizes.setdefault(split, []).append((image_path, info))
        views.append(make_view(cam, image_path, scale, bg))
    for split, items in sizes.items():
        check_same_size(items, f"split {split!r} of {where}")
    splits.setdefault("train", [])
    splits.setdefault("test", [])
    if not splits["train"]:
        raise GsgsError(f"{where}: no camera has split \"train\"; mark the training views")
    near, far = data.get("near"), data.get("far")
    points, colors = _inline_points(job, data)
    return Scene(views=views, splits=splits, source=str(job.root), format="job", background=bg,
                 near=None if near is None else float(near), far=None if far is None else float(far),
                 points=points, point_colors=colors, has_alpha=has_alpha)


def _inline_points(job: Job, data: dict) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Sparse points named by data.points (an x y z [red green blue] PLY, e.g. an SfM solve's)."""
    if not data.get("points"):
        return None, None
    from gsgs_engine.io.ply import read_ply_vertices

    path = _resolve(job.root, data["points"])
    v = read_ply_vertices(path)
    if not all(k in v for k in ("x", "y", "z")):
        raise GsgsError(f"{path}: a point cloud needs x, y, z properties (named by {job.spec_path} data.points)")
    points = np.stack([v["x"], v["y"], v["z"]], axis=1).astype(np.float32)
    bad = int((~np.isfinite(points).all(axis=1)).sum())
    if bad:
        raise GsgsError(f"{path}: {bad} of {len(points)} points have NaN or Inf coordinates (named by "
                        f"{job.spec_path} data.points); remove them or re-export the point cloud")
    colors = None
    if all(k in v for k in ("red", "green", "blue")):
        rgb = np.stack([v["red"], v["green"], v["blue"]], axis=1).astype(np.float32)
        colors = rgb / 255.0 if v["red"].dtype == np.uint8 else rgb
    return points, colors
