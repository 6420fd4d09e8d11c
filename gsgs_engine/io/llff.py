"""LLFF folders: poses_bounds.npy + images_N/ (downscaled photos), optional sparse/0 points."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import cameras_from_llff
from gsgs_engine.io.images import check_same_size, image_info, list_images, make_view
from gsgs_engine.io.scene import Scene

TEST_EVERY = 8  # the standard LLFF protocol: images 0, 8, 16, ... are held out


def image_folder(root: Path, factor: int = 8) -> Path:
    """images_<factor>/ when present, else the images_N/ closest to it, else images/."""
    preferred = root / f"images_{factor}"
    if preferred.is_dir():
        return preferred
    scaled = [(int(m.group(1)), p) for p in root.iterdir()
              if p.is_dir() and (m := re.fullmatch(r"images_(\d+)", p.name))]
    if scaled:
        return min(scaled, key=lambda np_: (abs(np_[0] - factor), -np_[0]))[1]
    if (root / "images").is_dir():
        return root / "images"
    raise GsgsError(f"{root}: no images_{factor}/, images_N/ or images/ folder next to poses_bounds.npy; "
                    "put the photos in one of them")


def heldout_split(count: int, every: int = TEST_EVERY) -> tuple[list[int], list[int]]:
    """(test, rest): every `every`-th index (i % every == 0) is test, the others are candidates."""
    test = [i for i in range(count) if i % every == 0]
    return test, [i for i in range(count) if i % every != 0]


def load_llff(path, factor: int = 8, resolution_scale: float = 1.0, background=(1.0, 1.0, 1.0)) -> Scene:
    """Splits: "test" every 8th image, "train" = "all_train" = the rest (sparse selection is
    load_scene's train_views / train_ids). World frame and bounds as stored (no recentring)."""
    path = Path(path)
    root = path.parent if path.is_file() else path
    poses_path = root / "poses_bounds.npy"
    try:
        array = np.load(poses_path, allow_pickle=False)
    except FileNotFoundError as exc:
        raise GsgsError(f"{poses_path}: missing; an LLFF folder needs poses_bounds.npy (run LLFF's imgs2poses.py)") from exc
    except (OSError, ValueError) as exc:
        raise GsgsError(f"{poses_path}: cannot read it as a NumPy array ({exc}); regenerate it with imgs2poses.py") from exc
    if array.ndim != 2 or array.shape[1] != 17:
        raise GsgsError(f"{poses_path}: expected shape (N, 17), got {array.shape}; regenerate it with imgs2poses.py")
    folder = image_folder(root, factor)
    paths = list_images(folder)
    if len(paths) != len(array):
        raise GsgsError(f"{poses_path}: {len(array)} poses but {len(paths)} images in {folder}; "
                        "keep exactly the photos the poses were computed for")
    infos = [image_info(p) for p in paths]
    check_same_size(list(zip(paths, infos)), f"folder {folder.name}")
    cameras = cameras_from_llff(array, (infos[0].width, infos[0].height), names=[p.stem for p in paths],
                                source=str(poses_path))
    bg = np.asarray(background, dtype=np.float32).reshape(3)
    views = [make_view(cam, p, resolution_scale, bg) for cam, p in zip(cameras, paths)]
    test, rest = heldout_split(len(views))
    points, colors = _sparse_points(root)
    bounds = array[:, 15:17]
    return Scene(views=views, splits={"train": rest, "test": test, "all_train": list(rest)}, source=str(root),
                 format="llff", background=bg, near=float(bounds.min()), far=float(bounds.max()),
                 points=points, point_colors=colors, has_alpha=False)


def _sparse_points(root: Path):
    """LLFF's imgs2poses keeps COLMAP's world frame, so sparse/0 points (when shipped) line up."""
    model = root / "sparse" / "0"
    if not any((model / f"points3D.{ext}").is_file() for ext in ("bin", "txt")):
        return None, None
    from gsgs_engine.io.colmap_model import read_points

    return read_points(model)
