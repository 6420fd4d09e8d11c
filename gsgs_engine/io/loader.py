"""load_scene: detect a dataset's format, load it, and pick the training views."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.io.scene import Scene
from gsgs_engine.io.selection import check_background, select_train

FORMATS = ("auto", "blender", "llff", "colmap", "photos", "job", "n3dv", "panoptic")


def detect_format(path) -> str:
    """The format of a scene path: job, panoptic, n3dv, blender, llff, colmap or photos (first match in that order)."""
    from gsgs_engine.io.colmap_model import find_model
    from gsgs_engine.io.nerf_synthetic import transforms_files
    from gsgs_engine.io.photos import photo_folder

    path = Path(path)
    if not path.exists():
        raise GsgsError(f"{path}: no such file or folder; pass a scene folder (NeRF-synthetic, LLFF, COLMAP, "
                        "job folder or photos)")
    if path.is_file():
        if path.name == "job.json":
            return "job"
        if path.name.startswith("transforms") and path.suffix == ".json":
            return "blender"
        if path.name == "poses_bounds.npy":
            return "llff"
        raise GsgsError(f"{path}: not a scene file (job.json, transforms*.json or poses_bounds.npy); "
                        "pass the scene folder instead")
    if (path / "job.json").is_file():
        return "job"
    from gsgs_engine.io.dynamic import is_n3dv
    from gsgs_engine.io.panoptic import is_panoptic

    if is_panoptic(path):
        return "panoptic"
    if is_n3dv(path):
        return "n3dv"
    if transforms_files(path):
        return "blender"
    if (path / "poses_bounds.npy").is_file():
        return "llff"
    if find_model(path) is not None:
        return "colmap"
    if photo_folder(path) is not None:
        return "photos"
    raise GsgsError(f"{path}: unknown scene format; looked for job.json, train_meta.json + ims/, transforms_*.json / transforms.json, "
                    "poses_bounds.npy, sparse/0/cameras.bin|txt and photos (.png/.jpg here or in images/)")


def load_scene(path, format: str = "auto", train_split: str | None = None, train_views: int | None = None,
               train_ids: list | None = None, resolution_scale: float | None = None,
               background=None, frames=None, max_side: int | None = None) -> Scene:
    """Load a scene; images stay on disk until a View asks for them.

    A scene much smaller or larger than usual comes back in rescaled units (scene.world_scale,
    gsgs_engine.io.world_scale.normalise_scene); results are written in world units.

    train_split: which split (NeRF-synthetic: which transforms file(s), "train+dense" joins) is the
      candidate pool for training; default "train".
    train_ids: the training views, as positions in that pool (ints) or view names / file stems
      (strings; a digit string that names no view is a position, as typed on a command line).
    train_views: N views spread evenly over the pool: round(linspace(0, len(pool) - 1, N)) (FSGS/DNGaussian).
    The full pool stays available as split "all_train"; "test" is never changed.
    frames (scenes with time): frame ids to keep ("0", "0-9", "0,5,9" or a list; io/dynamic.parse_frames),
      times renormalised over them; one frame trains a static model. Default: every frame.
    resolution_scale (default 1.0) resizes images and intrinsics; background (default white) is
    what RGBA images are composited on. For a job folder, unset arguments come from job.json.
    max_side (default: none) caps the longer side of every view after resolution_scale: a scene whose
      largest view is longer is loaded at the scale that brings it to max_side px (3DGS's own loader
      caps at 1600 px the same way). The scale used is scene.resolution_scale.
    """
    from gsgs_engine.io.world_scale import normalise_scene

    scene = _load_scene(path, format, train_split, train_views, train_ids, resolution_scale, background, frames)
    scale = 1.0 if resolution_scale is None else float(resolution_scale)
    if max_side is not None and max_side > 0:
        longest = max((max(v.camera.width, v.camera.height) for v in scene.views), default=0)
        if longest > max_side:
            scale *= max_side / longest
            # images are lazy: loading again at the capped scale reads no pixels
            scene = _load_scene(path, format, train_split, train_views, train_ids, scale, background, frames)
    scene.resolution_scale = scale
    return normalise_scene(scene)


def _load_scene(path, format, train_split, train_views, train_ids, resolution_scale, background, frames) -> Scene:
    from gsgs_engine.io.dynamic import parse_frames

    frames = parse_frames(frames)
    if format not in FORMATS:
        raise GsgsError(f"unknown scene format {format!r}; expected one of {', '.join(FORMATS)}")
    if resolution_scale is not None and not (math.isfinite(resolution_scale) and resolution_scale > 0):
        raise GsgsError(f"resolution_scale must be a positive number, got {resolution_scale}")
    if background is not None:
        background = check_background(background)
    fmt = detect_format(path) if format == "auto" else format
    if fmt == "job":
        from gsgs_engine.io.job_scene import SceneSource, load_job_scene

        scene = load_job_scene(path, train_split=train_split, train_views=train_views, train_ids=train_ids,
                               resolution_scale=resolution_scale, background=background, frames=frames)
        if isinstance(scene, SceneSource):  # the job names a scene folder: load that one
            return load_scene(scene.path, **scene.arguments)
        return scene
    scale = 1.0 if resolution_scale is None else float(resolution_scale)
    bg = (1.0, 1.0, 1.0) if background is None else background
    from gsgs_engine.io.dynamic import has_time

    if fmt == "panoptic":
        from gsgs_engine.io.panoptic import load_panoptic

        if train_ids is not None or train_split is not None:
            raise GsgsError(f"{path}: a Panoptic scene picks training cameras with --train-views N (test cameras "
                            "come from test_meta.json); --train-ids / --train-split do not apply")
        return load_panoptic(path, train_cameras=train_views, frames=frames, resolution_scale=scale, background=bg)
    if fmt == "n3dv" or (fmt == "blender" and has_time(path)):
        # Multi-view video: the protocol picks training *cameras* (train_views), camera 0 is the test camera.
        from gsgs_engine.io.dynamic import load_dynamic_scene

        if train_ids is not None or train_split is not None:
            raise GsgsError(f"{path}: a scene with time picks training cameras with --train-views N "
                            "(camera 0 is held out); --train-ids / --train-split do not apply")
        scene = load_dynamic_scene(path, format=fmt, train_cameras=train_views, resolution_scale=scale,
                                   background=bg)
        if frames is not None:
            from gsgs_engine.io.dynamic import select_frames

            scene = select_frames(scene, frames)
        return scene
    if frames is not None:
        raise GsgsError(f"{path}: frames picks frames of a scene with time (multi-view video); this {fmt} scene "
                        "has none, leave --frames unset")
    if fmt == "blender":
        from gsgs_engine.io.nerf_synthetic import load_nerf_synthetic

        scene = load_nerf_synthetic(path, train_split=train_split, resolution_scale=scale, background=bg)
        train_split = None  # already applied: it chose transforms files
    elif fmt == "llff":
        from gsgs_engine.io.llff import load_llff

        scene = load_llff(path, resolution_scale=scale, background=bg)
    elif fmt == "colmap":
        from gsgs_engine.io.colmap_model import load_colmap

        scene = load_colmap(path, resolution_scale=scale, background=bg)
    else:
        from gsgs_engine.io.photos import needs_sfm_error

        raise needs_sfm_error(path)
    return select_train(scene, train_split=train_split, train_ids=train_ids, train_views=train_views)
