"""COLMAP folders: sparse/0/{cameras,images,points3D}.bin|txt + images/ (read with pycolmap).

Distorted camera models are undistorted on the fly (see cameras.camera_from_colmap); models
other than the pinhole and radial-tangential ones are refused with the command that fixes them.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import COLMAP_MODELS, camera_from_colmap, rotmat_to_quat
from gsgs_engine.io.images import check_same_size, image_info, make_view
from gsgs_engine.io.scene import Scene

TEST_EVERY = 8


def find_model(root: Path) -> Path | None:
    """The folder holding cameras/images/points3D: sparse/0, sparse, or `root` itself."""
    for candidate in (root / "sparse" / "0", root / "sparse", root):
        if all(any((candidate / f"{n}.{ext}").is_file() for ext in ("bin", "txt"))
               for n in ("cameras", "images", "points3D")):
            return candidate
    return None


def _read(model: Path):
    # zlib must be loaded before pycolmap: otherwise a later zlib write in this process
    # (cv2.imwrite of a PNG, Pillow, np.savez_compressed) aborts with a double free.
    import zlib  # noqa: F401

    import pycolmap

    try:
        return pycolmap.Reconstruction(str(model))
    except Exception as exc:  # pycolmap raises bare RuntimeError / ValueError for corrupt files
        raise GsgsError(f"{model}: COLMAP model cannot be read ({exc}); re-export it with COLMAP") from exc


def read_points(model: Path) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Sparse points (N, 3) float32 and colours (N, 3) in [0, 1] of a COLMAP model folder."""
    rec = _read(Path(model))
    pts = [p for _, p in sorted(rec.points3D.items(), key=lambda kv: kv[0])]  # by id: deterministic order
    if not pts:
        return None, None
    xyz = np.array([p.xyz for p in pts], dtype=np.float32)
    rgb = np.array([p.color for p in pts], dtype=np.float32) / 255.0
    keep = np.all(np.isfinite(xyz), axis=1)
    return xyz[keep], rgb[keep]


def load_colmap(path, images: str = "images", resolution_scale: float = 1.0, background=(1.0, 1.0, 1.0),
                test_every: int = TEST_EVERY) -> Scene:
    """Registered images sorted by name; "test" = every `test_every`-th (i % test_every == 0),
    "train" = "all_train" = the rest (test_every=0 puts every image in train)."""
    root = Path(path)
    model = find_model(root)
    if model is None:
        raise GsgsError(f"{root}: no COLMAP model (cameras, images, points3D .bin or .txt) in sparse/0, sparse/ "
                        "or here; run `gsgs sfm PHOTOS --out DIR` to make one")
    image_dir = root / images if (root / images).is_dir() else None
    if image_dir is None:
        raise GsgsError(f"{root / images}: missing image folder for the COLMAP model in {model}; "
                        "put the photos there")
    rec = _read(model)
    registered = sorted((img for img in rec.images.values() if img.has_pose), key=lambda img: img.name)
    if not registered:
        raise GsgsError(f"{model}: the model has no registered images; re-run the reconstruction")
    bg = np.asarray(background, dtype=np.float32).reshape(3)
    views, entries = [], []
    for img in registered:
        image_path = image_dir / img.name
        info = image_info(image_path)
        cam = rec.cameras[img.camera_id]
        pose = np.asarray(img.cam_from_world().matrix(), dtype=np.float64)
        source = f"{model} image {img.name!r}"
        colmap_cam = _matching_size(cam, info, image_path)
        camera, undistortion = camera_from_colmap(rotmat_to_quat(pose[:, :3]), pose[:, 3], colmap_cam[0],
                                                  colmap_cam[1], info.width, info.height,
                                                  name=Path(img.name).stem, source=source)
        entries.append((image_path, info))
        views.append(make_view(camera, image_path, resolution_scale, bg, undistortion))
    # Several cameras share one model: share its Undistortion so its remap tables are built once.
    shared: dict = {}
    for view in views:
        u = view.loader.undistortion
        if u is not None:
            key = (u.source.fx, u.source.fy, u.source.cx, u.source.cy, u.source.width, tuple(sorted(u.coeffs.items())))
            view.loader = replace(view.loader, undistortion=shared.setdefault(key, u))
    check_same_size(entries, f"COLMAP model {model}")
    n = len(views)
    test = [i for i in range(n) if test_every and i % test_every == 0]
    rest = [i for i in range(n) if i not in test]
    points, colors = read_points(model)
    return Scene(views=views, splits={"train": rest, "test": test, "all_train": list(rest)}, source=str(root),
                 format="colmap", background=bg, points=points, point_colors=colors, has_alpha=False)


def _matching_size(cam, info, image_path: Path) -> tuple[str, list[float]]:
    """(model name, params) for the photo's actual size: images_4-style copies scale the intrinsics."""
    params = [float(p) for p in cam.params]
    model = cam.model.name
    if (cam.width, cam.height) == (info.width, info.height):
        return model, params
    sx, sy = info.width / cam.width, info.height / cam.height
    if abs(sx - sy) > 0.01 * sx:
        raise GsgsError(f"{image_path}: image is {info.width}x{info.height} but its COLMAP camera is "
                        f"{cam.width}x{cam.height} (another aspect ratio); use the photos the model was built from")
    # Focal and principal point scale with the image; distortion works on normalized coordinates.
    names = COLMAP_MODELS.get(model, ())
    scaled = [p * (sx if n in ("fx", "cx", "f") else sy if n in ("fy", "cy") else 1.0) for n, p in zip(names, params)]
    return model, scaled if names else params
