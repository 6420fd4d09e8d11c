"""CMU Panoptic captures in the Dynamic 3D Gaussians layout, and their sparse-camera protocol.

Layout (as Luiten et al. preprocess Panoptic):
    train_meta.json, test_meta.json   {"w", "h", "k", "w2c", "fn", "cam_id"}; k, w2c, fn and cam_id are
                                      per-frame lists (one entry per frame) of per-camera lists
    ims/<cam>/<frame>.jpg             the images, named by "fn" (relative to ims/)
    seg/<cam>/<frame>.png             optional foreground masks (the release has them for training cameras)

Cameras: "w2c" is world-to-camera in OpenCV axes (our Camera's R | t as is) and "k" the 3x3
intrinsics, used as given: Dynamic 3D Gaussians' renderer reads them with the pixel-centre-at-0.5
convention this project uses, so no half-pixel shift is applied.

Protocol (issue 31): the test split is every frame of test_meta.json's cameras (Panoptic: 0, 10, 15,
30); "all_train" is every frame of train_meta.json's cameras; "train" is every frame of N training
cameras spread evenly over train_meta.json's cameras in ascending id order,
ids[round(linspace(0, len(ids) - 1, N))] (numpy rounds half to even), the same rule as
io/selection.evenly_spaced. For the 27 Panoptic training cameras: N=3 -> 1, 16, 29; N=6 -> 1, 6,
12, 19, 24, 29; N=9 -> 1, 4, 7, 12, 16, 19, 23, 26, 29 (`sparse_camera_ids`).
Frames are the positions in the meta's per-frame lists; `frames` keeps some of them (text such as
"0", "0-9" or "0,5,9", see io/dynamic.parse_frames). Time is normalised over the frames loaded:
first 0, last 1 (one frame: time 0, which the effect plan trains as a static scene).
Camera.extra holds "camera_index" (the Panoptic camera id), "frame" and, where seg/ has the file,
"mask_path" (the View type has no mask field; `load_mask(view)` reads it for a dynamic-region score).
stdlib + numpy at module level, like the rest of gsgs_engine.io.
"""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.io.dynamic import normalised_times
from gsgs_engine.io.images import image_info, make_view
from gsgs_engine.io.scene import Scene, View
from gsgs_engine.io.selection import evenly_spaced

TRAIN_META, TEST_META = "train_meta.json", "test_meta.json"
_PER_FRAME = ("k", "w2c", "fn", "cam_id")


def is_panoptic(path) -> bool:
    """train_meta.json next to an ims/ folder."""
    root = Path(path)
    root = root.parent if root.is_file() else root
    return (root / TRAIN_META).is_file() and (root / "ims").is_dir()


def sparse_camera_ids(camera_ids, n: int, source: str = "scene") -> list[int]:
    """n of the training cameras, evenly spread over them in ascending id order (ends included)."""
    ids = sorted(int(c) for c in camera_ids)
    return [ids[i] for i in evenly_spaced(len(ids), n, source)]


def read_meta(path: Path) -> dict:
    """A meta file checked for shape: w, h, and per-frame lists of equal length, one entry per camera."""
    if not path.is_file():
        raise GsgsError(f"{path}: missing; a Panoptic / Dynamic 3D Gaussians folder needs {TRAIN_META} and "
                        f"{TEST_META} next to ims/")
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise GsgsError(f"{path}: cannot read it as JSON ({exc}); regenerate it") from exc
    if not isinstance(meta, dict):
        raise GsgsError(f"{path}: expected an object with w, h, k, w2c, fn and cam_id")
    missing = [k for k in ("w", "h", *_PER_FRAME) if k not in meta]
    if missing:
        raise GsgsError(f"{path}: no {', '.join(repr(m) for m in missing)}; a Dynamic 3D Gaussians meta file "
                        "holds w, h and per-frame lists k, w2c, fn, cam_id")
    for key in _PER_FRAME:
        if not isinstance(meta[key], list) or not meta[key] or not all(isinstance(x, list) for x in meta[key]):
            raise GsgsError(f"{path}: {key!r} must be a non-empty list with one list per frame")
    lengths = {key: len(meta[key]) for key in _PER_FRAME}
    if len(set(lengths.values())) != 1:
        shown = ", ".join(f"{k} {n}" for k, n in lengths.items())
        raise GsgsError(f"{path}: the per-frame lists differ in length ({shown} frames); regenerate the file so "
                        "k, w2c, fn and cam_id each hold one entry per frame")
    for t in range(lengths["fn"]):
        counts = {key: len(meta[key][t]) for key in _PER_FRAME}
        if len(set(counts.values())) != 1:
            shown = ", ".join(f"{k} {n}" for k, n in counts.items())
            raise GsgsError(f"{path}: frame {t} lists a different number of cameras per key ({shown}); every "
                            "key needs one entry per camera")
        if meta["cam_id"][t] != meta["cam_id"][0]:
            raise GsgsError(f"{path}: frame {t} lists cameras {meta['cam_id'][t]} but frame 0 lists "
                            f"{meta['cam_id'][0]}; every frame must list the same cameras in the same order")
    try:
        meta["w"], meta["h"] = int(meta["w"]), int(meta["h"])
    except (TypeError, ValueError):
        raise GsgsError(f"{path}: w and h must be whole numbers (got {meta['w']!r}, {meta['h']!r})") from None
    return meta


def _camera(meta: dict, t: int, i: int, where: str) -> Camera:
    try:
        k = np.asarray(meta["k"][t][i], dtype=np.float64)
        w2c = np.asarray(meta["w2c"][t][i], dtype=np.float64)
    except (TypeError, ValueError):
        raise GsgsError(f"{where}: k / w2c are not numbers; regenerate the meta file") from None
    if k.shape != (3, 3) or w2c.shape != (4, 4):
        raise GsgsError(f"{where}: k must be 3x3 and w2c 4x4 (got {k.shape} and {w2c.shape}); regenerate the "
                        "meta file")
    cam = Camera(R=w2c[:3, :3], t=w2c[:3, 3], fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2],
                 width=meta["w"], height=meta["h"])
    return cam.validate(where)


def load_panoptic(path, train_cameras: int | None = None, frames: list[int] | None = None,
                  resolution_scale: float = 1.0, background=(1.0, 1.0, 1.0)) -> Scene:
    """The scene with splits train (N cameras, or all), all_train and test; see the module docstring."""
    root = Path(path)
    root = root.parent if root.is_file() else root
    if not (root / "ims").is_dir():
        raise GsgsError(f"{root}: no ims/ folder; a Panoptic / Dynamic 3D Gaussians folder keeps its images in "
                        "ims/<camera>/<frame>.jpg")
    metas = {"train": read_meta(root / TRAIN_META), "test": read_meta(root / TEST_META)}
    total = len(metas["train"]["fn"])
    if len(metas["test"]["fn"]) != total:
        raise GsgsError(f"{root / TEST_META}: {len(metas['test']['fn'])} frames but {TRAIN_META} has {total}; "
                        "both files must list the same frames")
    if frames is None:
        frames = list(range(total))
    bad = [f for f in frames if not 0 <= f < total]
    if bad:
        raise GsgsError(f"{root}: frame {bad[0]} does not exist; the meta files list frames 0..{total - 1}")
    frames = sorted(set(frames))
    times = normalised_times(frames)
    bg = np.asarray(background, dtype=np.float32).reshape(3)
    views: list[View] = []
    splits: dict[str, list[int]] = {"train": [], "test": []}
    for split, meta in metas.items():
        meta_path = root / (TRAIN_META if split == "train" else TEST_META)
        sizes_checked = False
        for f, time in zip(frames, times):
            for i, cam_id in enumerate(meta["cam_id"][f]):
                where = f"{meta_path.name} frame {f} camera {cam_id}"
                image = root / "ims" / str(meta["fn"][f][i])
                if not image.is_file():
                    raise GsgsError(f"{image}: missing, but {where} lists it; restore the file or drop frame {f} "
                                    f"from both meta files (or train on other frames with --frames)")
                if not sizes_checked:  # one header per meta file: the release's images all share w x h
                    info = image_info(image)
                    if (info.width, info.height) != (meta["w"], meta["h"]):
                        raise GsgsError(f"{image}: image is {info.width}x{info.height} but {meta_path.name} says "
                                        f"w={meta['w']}, h={meta['h']}; fix w / h or the images")
                    sizes_checked = True
                cam = _camera(meta, f, i, where)
                extra = {"camera_index": int(cam_id), "frame": int(f)}
                mask = (root / "seg" / str(meta["fn"][f][i])).with_suffix(".png")
                if mask.is_file():
                    extra["mask_path"] = mask
                cam = replace(cam, name=Path(str(meta["fn"][f][i])).with_suffix("").as_posix(), time=float(time),
                              extra=extra)
                splits[split].append(len(views))
                views.append(make_view(cam, image, resolution_scale, bg))
    scene = Scene(views=views, splits=splits, source=str(root), format="panoptic", background=bg, has_alpha=False)
    scene.splits["all_train"] = list(scene.splits["train"])
    if train_cameras is not None:
        chosen = set(sparse_camera_ids(metas["train"]["cam_id"][0], train_cameras, str(root)))
        scene.splits["train"] = [i for i in scene.splits["train"] if views[i].camera.extra["camera_index"] in chosen]
    return scene


def load_mask(view: View) -> np.ndarray | None:
    """The view's foreground mask (bool, H x W at the view's size), or None when seg/ has none."""
    path = view.camera.extra.get("mask_path")
    if path is None:
        return None
    import cv2

    from gsgs_engine.io.images import decode_image

    m = decode_image(Path(path))[..., 0]
    size = (view.camera.width, view.camera.height)
    if (m.shape[1], m.shape[0]) != size:
        m = cv2.resize(m, size, interpolation=cv2.INTER_NEAREST)
    return m > 0.5
