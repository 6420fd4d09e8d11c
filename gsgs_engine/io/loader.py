"""load_scene: detect a dataset's format, load it, and pick the training views."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.io.scene import Scene

FORMATS = ("auto", "blender", "llff", "colmap", "photos", "job", "n3dv")


def detect_format(path) -> str:
    """The format of a scene path: job, blender, llff, colmap or photos (first match in that order)."""
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
    raise GsgsError(f"{path}: unknown scene format; looked for job.json, transforms_*.json / transforms.json, "
                    "poses_bounds.npy, sparse/0/cameras.bin|txt and photos (.png/.jpg here or in images/)")


def load_scene(path, format: str = "auto", train_split: str | None = None, train_views: int | None = None,
               train_ids: list | None = None, resolution_scale: float | None = None,
               background=None) -> Scene:
    """Load a scene; images stay on disk until a View asks for them.

    A scene much smaller or larger than usual comes back in rescaled units (scene.world_scale,
    gsgs_engine.io.world_scale.normalise_scene); results are written in world units.

    train_split: which split (NeRF-synthetic: which transforms file(s), "train+dense" joins) is the
      candidate pool for training; default "train".
    train_ids: the training views, as positions in that pool (ints) or view names / file stems
      (strings; a digit string that names no view is a position, as typed on a command line).
    train_views: N views spread evenly over the pool: round(linspace(0, len(pool) - 1, N)) (FSGS/DNGaussian).
    The full pool stays available as split "all_train"; "test" is never changed.
    resolution_scale (default 1.0) resizes images and intrinsics; background (default white) is
    what RGBA images are composited on. For a job folder, unset arguments come from job.json.
    """
    from gsgs_engine.io.world_scale import normalise_scene

    return normalise_scene(_load_scene(path, format, train_split, train_views, train_ids, resolution_scale,
                                       background))


def _load_scene(path, format, train_split, train_views, train_ids, resolution_scale, background) -> Scene:
    if format not in FORMATS:
        raise GsgsError(f"unknown scene format {format!r}; expected one of {', '.join(FORMATS)}")
    if resolution_scale is not None and not (math.isfinite(resolution_scale) and resolution_scale > 0):
        raise GsgsError(f"resolution_scale must be a positive number, got {resolution_scale}")
    if background is not None:
        background = _check_background(background)
    fmt = detect_format(path) if format == "auto" else format
    if fmt == "job":
        from gsgs_engine.io.job_scene import load_job_scene

        return load_job_scene(path, train_split=train_split, train_views=train_views, train_ids=train_ids,
                              resolution_scale=resolution_scale, background=background)
    scale = 1.0 if resolution_scale is None else float(resolution_scale)
    bg = (1.0, 1.0, 1.0) if background is None else background
    from gsgs_engine.io.dynamic import has_time

    if fmt == "n3dv" or (fmt == "blender" and has_time(path)):
        # Multi-view video: the protocol picks training *cameras* (train_views), camera 0 is the test camera.
        from gsgs_engine.io.dynamic import load_dynamic_scene

        if train_ids is not None or train_split is not None:
            raise GsgsError(f"{path}: a scene with time picks training cameras with --train-views N "
                            "(camera 0 is held out); --train-ids / --train-split do not apply")
        return load_dynamic_scene(path, format=fmt, train_cameras=train_views, resolution_scale=scale,
                                  background=bg)
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


def _check_background(background) -> np.ndarray:
    bg = np.asarray(background, dtype=np.float32).reshape(-1)
    if bg.shape != (3,) or not np.all(np.isfinite(bg)) or bg.min() < 0 or bg.max() > 1:
        raise GsgsError(f"background must be three numbers in [0, 1] (RGB), got {background!r}")
    return bg


def select_train(scene: Scene, train_split: str | None = None, train_ids: list | None = None,
                 train_views: int | None = None) -> Scene:
    """Set scene.splits["train"] from the pool (split `train_split`, else "all_train", else "train")."""
    if train_ids is not None and train_views is not None:
        raise GsgsError("pass either train_ids or train_views, not both")
    if train_split is not None:
        if train_split not in scene.splits:
            raise GsgsError(f"{scene.source}: no split {train_split!r} to train on; available: "
                            f"{', '.join(scene.splits)}")
        pool = list(scene.splits[train_split])
    else:
        pool = list(scene.splits.get("all_train", scene.splits["train"]))
    scene.splits["all_train"] = pool
    if train_ids is not None:
        scene.splits["train"] = [pool[i] for i in _resolve_ids(scene, pool, train_ids)]
    elif train_views is not None:
        scene.splits["train"] = [pool[i] for i in evenly_spaced(len(pool), train_views, scene.source)]
    else:
        scene.splits["train"] = list(pool)
    return scene


def evenly_spaced(count: int, n: int, source: str = "scene") -> list[int]:
    """n indices spread over range(count), ends included: round(linspace(0, count - 1, n))."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise GsgsError(f"train_views must be a positive whole number, got {n!r}")
    if n > count:
        raise GsgsError(f"{source}: train_views={n} but only {count} candidate training views; ask for at most {count}")
    return [int(i) for i in np.round(np.linspace(0, count - 1, n))]


def _resolve_ids(scene: Scene, pool: list[int], train_ids) -> list[int]:
    """Positions in `pool` of train_ids given as positions (ints) or view names / file stems (strings)."""
    by_name: dict[str, int] = {}
    for pos, idx in enumerate(pool):
        view = scene.views[idx]
        by_name.setdefault(view.name, pos)
        by_name.setdefault(Path(view.name).name, pos)
        if view.image_path is not None:
            by_name.setdefault(Path(view.image_path).name, pos)
            by_name.setdefault(Path(view.image_path).stem, pos)
    out = []
    for item in train_ids:
        if isinstance(item, (int, np.integer)) and not isinstance(item, bool):
            if not 0 <= item < len(pool):
                raise GsgsError(f"{scene.source}: train id {item} is out of range; the pool has {len(pool)} views "
                                f"(ids 0..{len(pool) - 1})")
            pos = int(item)
        elif isinstance(item, str) and item in by_name:
            pos = by_name[item]
        elif isinstance(item, str) and item.strip().isdigit() and int(item) < len(pool):
            pos = int(item)  # "5" from a command line: a position, unless a view is named "5"
        else:
            raise GsgsError(f"{scene.source}: train id {item!r} names no candidate training view; use positions "
                            f"0..{len(pool) - 1} or view names such as {scene.views[pool[0]].name!r}")
        if pos in out:
            raise GsgsError(f"{scene.source}: train id {item!r} is listed twice")
        out.append(pos)
    if not out:
        raise GsgsError(f"{scene.source}: train_ids is empty; list at least one training view")
    return out
