"""NeRF-synthetic / instant-ngp folders: transforms_<split>.json (or one transforms.json) + images."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import camera_from_nerf, undistortion_for
from gsgs_engine.io.images import check_same_size, find_image, image_info, make_view
from gsgs_engine.io.scene import Scene

NEAR, FAR = 2.0, 6.0  # the NeRF-synthetic convention (the objects sit within radius ~1.5 of the origin)
CAMERA_DISTANCE = 4.0311289  # ... seen from cameras this far from the origin
_DISTORTION_KEYS = ("k1", "k2", "k3", "p1", "p2")  # nerfstudio / instant-ngp OPENCV keys
_NUMERIC_KEYS = ("camera_angle_x", "camera_angle_y", "fl_x", "fl_y", "cx", "cy", "w", "h") + _DISTORTION_KEYS
_SPLIT_ORDER = {"train": 0, "val": 1, "test": 2}


def transforms_files(root: Path) -> dict[str, Path]:
    """Split name -> transforms file; a lone transforms.json is the split "all"."""
    files = {p.stem[len("transforms_"):]: p for p in sorted(root.glob("transforms_*.json"))}
    if not files and (root / "transforms.json").is_file():
        files = {"all": root / "transforms.json"}
    return dict(sorted(files.items(), key=lambda kv: (_SPLIT_ORDER.get(kv[0], 3), kv[0])))


def _read_json(path: Path) -> dict:
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise GsgsError(f"{path}: not valid JSON ({exc}); fix the file or re-export the dataset") from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list):
        raise GsgsError(f"{path}: expected an object with a \"frames\" list (NeRF transforms format)")
    return meta


def _frame_camera(meta: dict, frame: dict, image_path: Path, name: str, where: str):
    """(Camera, Undistortion | None, ImageInfo) of one frame; frame keys override file-level ones."""
    get = lambda key: frame.get(key, meta.get(key))  # noqa: E731
    if "transform_matrix" not in frame:
        raise GsgsError(f"{where}: frame has no transform_matrix; every frame needs its camera-to-world matrix")
    try:
        c2w = np.array(frame["transform_matrix"], dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise GsgsError(f"{where}: transform_matrix is not a 4x4 list of numbers ({exc})") from exc
    if not np.all(np.isfinite(c2w)):
        raise GsgsError(f"{where}: transform_matrix contains NaN or Inf; fix or remove this frame")
    for key in _NUMERIC_KEYS:
        value = get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))
                                  or not np.isfinite(value)):
            raise GsgsError(f"{where}: {key} must be a finite number (got {value!r}); fix the transforms file")
    info = image_info(image_path)
    # Intrinsics refer to w x h when given; photos resized since then scale them proportionally.
    ref_w, ref_h = get("w") or info.width, get("h") or info.height
    cam = camera_from_nerf(c2w, int(round(ref_w)), int(round(ref_h)), get("camera_angle_x"), get("camera_angle_y"),
                           get("fl_x"), get("fl_y"), get("cx"), get("cy"), name=name, near=NEAR, far=FAR, source=where)
    if (cam.width, cam.height) != (info.width, info.height):
        if abs(info.width / cam.width - info.height / cam.height) > 0.01 * info.width / cam.width:
            raise GsgsError(f"{image_path}: image is {info.width}x{info.height} but {where} describes "
                            f"{cam.width}x{cam.height} (another aspect ratio); fix w/h or the image")
        sx, sy = info.width / cam.width, info.height / cam.height
        cam = replace(cam, fx=cam.fx * sx, fy=cam.fy * sy, cx=cam.cx * sx, cy=cam.cy * sy,
                      width=info.width, height=info.height)
    model = get("camera_model")
    if model not in (None, "OPENCV", "PINHOLE", "SIMPLE_PINHOLE"):
        raise GsgsError(f"{where}: camera_model {model} is not supported; undistort the images to a pinhole "
                        "camera first (e.g. nerfstudio's ns-process-data or colmap image_undistorter)")
    coeffs = {k: float(get(k)) for k in _DISTORTION_KEYS if get(k)}
    cam, undistortion = undistortion_for(cam, coeffs)
    return cam, undistortion, info


def load_nerf_synthetic(path, train_split: str | None = None, resolution_scale: float = 1.0,
                        background=(1.0, 1.0, 1.0)) -> Scene:
    """Every transforms_<split>.json becomes a split; `train_split` ("dense", or "train+dense")
    names the file(s) used as "train" (the file called train stays available as split
    "transforms_train"). A lone transforms.json is split every 8th frame for "test"."""
    path = Path(path)
    root = path.parent if path.is_file() else path
    files = transforms_files(root)
    if not files:
        raise GsgsError(f"{root}: no transforms_<split>.json or transforms.json here; "
                        "point at a NeRF-synthetic / instant-ngp dataset folder")
    bg = np.asarray(background, dtype=np.float32).reshape(3)
    views, splits, has_alpha = [], {}, False
    for split, json_path in files.items():
        meta = _read_json(json_path)
        entries, indices = [], []
        for i, frame in enumerate(meta["frames"]):
            where = f"{json_path} frame {i}"
            if not isinstance(frame, dict) or "file_path" not in frame:
                raise GsgsError(f"{where}: frame has no file_path")
            rel = str(frame["file_path"])
            image_path = find_image(json_path.parent, rel)
            if image_path is None:
                raise GsgsError(f"{json_path.parent / rel}: image file is missing (listed in {json_path.name} "
                                f"frame {i}); restore it or remove the frame")
            name = rel[2:] if rel.startswith("./") else rel
            name = name.rsplit(".", 1)[0] if Path(name).suffix.lower() in (".png", ".jpg", ".jpeg", ".exr") else name
            cam, undistortion, info = _frame_camera(meta, frame, image_path, name, where)
            has_alpha |= info.channels in (2, 4)
            entries.append((image_path, info))
            indices.append(len(views))
            views.append(make_view(cam, image_path, resolution_scale, bg, undistortion))
        check_same_size(entries, f"split {split!r} ({json_path.name})")
        splits[split] = indices
    splits = _assign_train(splits, train_split, root)
    ratio = _size_ratio(views)
    if ratio != 1.0:  # a rescaled copy: the convention's near / far follow the cameras
        views = [replace(v, camera=replace(v.camera, near=NEAR * ratio, far=FAR * ratio)) for v in views]
    return Scene(views=views, splits=splits, source=str(root), format="blender", background=bg,
                 near=NEAR * ratio, far=FAR * ratio, has_alpha=has_alpha)


def _size_ratio(views) -> float:
    """Median camera distance from the origin over the convention's 4.03 units; 1 within a factor 1.5
    (every NeRF-synthetic scene keeps NEAR / FAR exactly), the ratio itself for rescaled copies."""
    if not views:
        return 1.0
    dist = float(np.median([np.linalg.norm(v.camera.center) for v in views]))
    ratio = dist / CAMERA_DISTANCE
    return 1.0 if not np.isfinite(ratio) or ratio <= 0 or abs(np.log(ratio)) < np.log(1.5) else ratio


def _assign_train(splits: dict[str, list[int]], train_split: str | None, root: Path) -> dict[str, list[int]]:
    if set(splits) == {"all"}:
        if train_split not in (None, "all", "train"):
            raise GsgsError(f"{root}: only transforms.json is present, so there is no split {train_split!r}; "
                            "leave train_split unset")
        every = splits["all"]
        return {"all": every, "train": [j for k, j in enumerate(every) if k % 8], "test": every[::8]}
    wanted = (train_split or "train").split("+")
    missing = [s for s in wanted if s not in splits]
    if missing:
        raise GsgsError(f"{root}: no transforms_{missing[0]}.json for train split {missing[0]!r}; "
                        f"available splits: {', '.join(splits)}")
    out = dict(splits)
    if wanted != ["train"] and "train" in splits:
        out["transforms_train"] = splits["train"]
    out["train"] = [i for s in wanted for i in splits[s]]
    out.setdefault("test", [])
    return out
