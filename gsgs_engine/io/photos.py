"""A folder of photos without poses: listed here, posed by `gsgs sfm`, never loaded directly."""

from __future__ import annotations

from pathlib import Path

from gsgs_engine import GsgsError
from gsgs_engine.io.images import list_images


def photo_folder(root: Path) -> Path | None:
    """The folder holding the photos (`root` or root/images), or None when there are none."""
    for folder in (root, root / "images"):
        if folder.is_dir() and list_images(folder):
            return folder
    return None


def list_photos(root) -> list[Path]:
    """The photos of a photo folder, sorted by name (what `gsgs sfm` reconstructs)."""
    folder = photo_folder(Path(root))
    if folder is None:
        raise GsgsError(f"{root}: no photos (.png, .jpg, ...) here or in images/; add the photos to reconstruct")
    return list_images(folder)


def needs_sfm_error(path) -> GsgsError:
    """Photos have no cameras yet: the error that says how to get them (SfM writes a COLMAP folder)."""
    count = len(list_photos(path))
    return GsgsError(f"{path}: {count} photos without camera poses; run `gsgs sfm {path} --out DIR` first, "
                     "then load DIR (a COLMAP folder)")


def load_photos(path, **_ignored):
    raise needs_sfm_error(path)
