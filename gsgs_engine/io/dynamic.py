"""Multi-view video scenes: every (camera, frame) is a View whose Camera carries a time in [0, 1].

Layouts:
- Neural 3D Video: poses_bounds.npy (one LLFF row per camera) + cam00.mp4, cam01.mp4, ... or
  per-camera frame folders cam00/ (images directly or in cam00/images/). Video frames are
  decoded lazily with OpenCV, one frame per request.
- NeRF-synthetic JSON with a per-frame "time" (D-NeRF style). Frames are grouped into cameras by
  "camera_id", else "camera_name", else identical transform_matrix. With several cameras the
  multi-view protocol below applies; a monocular capture (every frame its own camera, as D-NeRF)
  keeps the file's train/test splits.

Protocol (Neural 3D Video, as the paper): camera 0 is the test camera; N training cameras are
spread evenly over the others (round(linspace(0, len(rest) - 1, N))). Time is normalised so the
first frame is 0 and the last is 1. Camera.extra["camera_index"] / ["frame"] name each view.
stdlib + numpy at module level (cv2 inside functions), like the rest of gsgs_engine.io.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.io.scene import Scene, View

VIDEO_EXTENSIONS = (".mp4", ".mov", ".avi", ".mkv", ".webm")
_CAM_RE = re.compile(r"^cam(\d+)$", re.IGNORECASE)


# -- detection ---------------------------------------------------------------------------------
def is_n3dv(path) -> bool:
    """poses_bounds.npy next to camNN videos or camNN/ frame folders (not an LLFF photo folder)."""
    root = Path(path)
    root = root.parent if root.is_file() else root
    return (root / "poses_bounds.npy").is_file() and bool(_camera_sources(root))


def has_time(path) -> bool:
    """A NeRF-synthetic folder whose frames carry "time", or a Neural-3D-Video folder."""
    root = Path(path)
    root = root.parent if root.is_file() else root
    if is_n3dv(root):
        return True
    from gsgs_engine.io.nerf_synthetic import transforms_files

    for json_path in transforms_files(root).values():
        try:
            frames = json.loads(json_path.read_text()).get("frames") or []
        except (OSError, ValueError, AttributeError):
            return False
        if frames and isinstance(frames[0], dict) and "time" in frames[0]:
            return True
    return False


def load_dynamic_scene(path, format: str = "auto", train_cameras: int | None = None, test_camera: int = 0,
                       max_frames: int | None = None, resolution_scale: float = 1.0,
                       background=(1.0, 1.0, 1.0)) -> Scene:
    """Load a multi-view video scene; `format` is "auto", "n3dv" or "blender" (JSON with time).

    train_cameras: N training cameras evenly from the non-test cameras (default: all of them).
    max_frames: keep at most this many frames, evenly spaced, first and last included.
    Splits: "test" = every frame of camera `test_camera`, "all_train" = every frame of the
    other cameras, "train" = every frame of the chosen training cameras.
    """
    root = Path(path)
    root = root.parent if root.is_file() else root
    if not root.exists():
        raise GsgsError(f"{root}: no such folder; pass a Neural-3D-Video folder or a NeRF-synthetic folder with time")
    if format == "auto":
        format = "n3dv" if is_n3dv(root) else "blender"
    if format == "n3dv":
        scene = load_n3dv(root, max_frames=max_frames, resolution_scale=resolution_scale, background=background)
    elif format == "blender":
        scene = load_nerf_with_time(root, max_frames=max_frames, resolution_scale=resolution_scale,
                                    background=background)
        if not is_multiview(scene):
            if train_cameras is not None:
                raise GsgsError(f"{root}: a monocular capture (one camera per frame) has no training cameras to "
                                "choose; leave train_cameras unset")
            return scene
    else:
        raise GsgsError(f"unknown dynamic scene format {format!r}; use auto, n3dv or blender")
    return apply_camera_protocol(scene, train_cameras=train_cameras, test_camera=test_camera)


# -- the protocol ------------------------------------------------------------------------------
def camera_index(view: View) -> int:
    return int(view.camera.extra["camera_index"])


def num_cameras(scene: Scene) -> int:
    return len({camera_index(v) for v in scene.views})


def is_multiview(scene: Scene) -> bool:
    """At least two cameras, and some camera sees more than one frame (D-NeRF's moving camera does not)."""
    per_cam: dict[int, int] = {}
    for v in scene.views:
        per_cam[camera_index(v)] = per_cam.get(camera_index(v), 0) + 1
    return len(per_cam) >= 2 and max(per_cam.values()) > 1


def evenly_spaced_cameras(rest: list[int], n: int, source: str) -> list[int]:
    """n of the cameras in `rest`, evenly spread, first and last included."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise GsgsError(f"train_cameras must be a positive whole number, got {n!r}")
    if n > len(rest):
        raise GsgsError(f"{source}: {n} training cameras asked but only {len(rest)} besides the test camera; "
                        f"ask for at most {len(rest)}")
    return [rest[int(i)] for i in np.round(np.linspace(0, len(rest) - 1, n))]


def apply_camera_protocol(scene: Scene, train_cameras: int | None = None, test_camera: int = 0) -> Scene:
    cams = sorted({camera_index(v) for v in scene.views})
    if test_camera not in cams:
        raise GsgsError(f"{scene.source}: there is no camera {test_camera} (cameras {cams[0]}..{cams[-1]}); "
                        "pick an existing test camera")
    rest = [c for c in cams if c != test_camera]
    if not rest:
        raise GsgsError(f"{scene.source}: only one camera; a multi-view video needs at least two")
    chosen = rest if train_cameras is None else evenly_spaced_cameras(rest, train_cameras, scene.source)
    by_cam = lambda wanted: [i for i, v in enumerate(scene.views) if camera_index(v) in wanted]  # noqa: E731
    scene.splits = {"train": by_cam(set(chosen)), "test": by_cam({test_camera}), "all_train": by_cam(set(rest))}
    return scene


def frame_times(frame_ids: list[int], total: int) -> list[float]:
    """Frame index -> time in [0, 1] over the whole clip (first frame 0, last frame 1)."""
    return [0.0 if total <= 1 else f / (total - 1) for f in frame_ids]


def normalised_times(frame_ids: list[int]) -> list[float]:
    """Times over the frames loaded: the first 0, the last 1 (a single frame: 0)."""
    lo, hi = min(frame_ids), max(frame_ids)
    return [0.0 if hi == lo else (f - lo) / (hi - lo) for f in frame_ids]


def parse_frames(spec) -> list[int] | None:
    """Frame ids from "0", "0-9", "0,5,9" or "0-4,10" (or an int / a list of ints); None keeps every frame."""
    if spec is None:
        return None
    if isinstance(spec, (int, np.integer)) and not isinstance(spec, bool):
        spec = str(int(spec))
    if isinstance(spec, list) and all(isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in spec):
        spec = ",".join(str(int(x)) for x in spec)
    out: list[int] = []
    for part in (str(spec).split(",") if isinstance(spec, str) else [None]):
        m = re.fullmatch(r"\s*(\d+)\s*(?:-\s*(\d+)\s*)?", part or "")
        if not m or (m.group(2) is not None and int(m.group(2)) < int(m.group(1))):
            raise GsgsError(f"frames {spec!r}: expected frame ids such as 0, 0-9 or 0,5,9 (ranges ascending)")
        lo = int(m.group(1))
        out.extend(range(lo, int(m.group(2) or lo) + 1))
    return sorted(set(out))


def select_frames(scene: Scene, frames: list[int]) -> Scene:
    """Keep the views of these frames (Camera.extra["frame"]); times renormalised over the frames kept."""
    present = sorted({int(v.camera.extra["frame"]) for v in scene.views})
    missing = [f for f in frames if f not in present]
    if missing:
        raise GsgsError(f"{scene.source}: frame {missing[0]} does not exist; frames are "
                        f"{present[0]}..{present[-1]} ({len(present)} frames)")
    keep = [i for i, v in enumerate(scene.views) if int(v.camera.extra["frame"]) in set(frames)]
    time_of = dict(zip(sorted(frames), normalised_times(sorted(frames))))
    remap = {old: new for new, old in enumerate(keep)}
    scene.views = [replace(scene.views[i], camera=replace(scene.views[i].camera,
                                                          time=time_of[int(scene.views[i].camera.extra["frame"])]))
                   for i in keep]
    scene.splits = {k: [remap[i] for i in v if i in remap] for k, v in scene.splits.items()}
    return scene


def pick_frames(total: int, max_frames: int | None, source: str) -> list[int]:
    if total < 1:
        raise GsgsError(f"{source}: no frames")
    if max_frames is None or max_frames >= total:
        return list(range(total))
    if max_frames < 1:
        raise GsgsError(f"max_frames must be at least 1, got {max_frames}")
    return sorted({int(i) for i in np.round(np.linspace(0, total - 1, max_frames))})


# -- Neural 3D Video ---------------------------------------------------------------------------
def _camera_sources(root: Path) -> list[Path]:
    """camNN videos or camNN/ folders, sorted by NN (videos win when both exist)."""
    found: dict[int, Path] = {}
    for p in root.iterdir():
        stem = p.stem if p.is_file() else p.name
        m = _CAM_RE.match(stem)
        if not m:
            continue
        if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS:
            found[int(m.group(1))] = p
        elif p.is_dir():
            found.setdefault(int(m.group(1)), p)
    return [found[k] for k in sorted(found)]


def _frame_files(folder: Path) -> list[Path]:
    from gsgs_engine.io.images import list_images

    inner = folder / "images"
    files = list_images(inner) if inner.is_dir() else []
    return files or list_images(folder)


@dataclass(frozen=True)
class VideoFrameLoader:
    """A View's loader: decode frame `index` of a video with OpenCV, resize to `size` = (w, h)."""

    path: Path
    index: int
    size: tuple[int, int]

    def __call__(self) -> np.ndarray:
        try:
            import cv2
        except ImportError as exc:
            raise GsgsError(f"{self.path}: decoding video needs OpenCV; run this in the gsgs engine's Python") from exc
        cap = cv2.VideoCapture(str(self.path))
        try:
            if not cap.isOpened():
                raise GsgsError(f"{self.path}: OpenCV cannot open this video; re-encode it as H.264 MP4")
            cap.set(cv2.CAP_PROP_POS_FRAMES, self.index)
            ok, frame = cap.read()
        finally:
            cap.release()
        if not ok or frame is None:
            raise GsgsError(f"{self.path}: cannot decode frame {self.index}; the video is shorter or damaged")
        img = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
        if (img.shape[1], img.shape[0]) != tuple(self.size):
            img = cv2.resize(img, tuple(self.size), interpolation=cv2.INTER_AREA)
        return img


def video_info(path: Path) -> tuple[int, int, int]:
    """(width, height, frame count) of a video."""
    try:
        import cv2
    except ImportError as exc:
        raise GsgsError(f"{path}: reading video needs OpenCV; run this in the gsgs engine's Python") from exc
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise GsgsError(f"{path}: OpenCV cannot open this video; re-encode it as H.264 MP4")
        w, h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()
    if w <= 0 or h <= 0 or n <= 0:
        raise GsgsError(f"{path}: OpenCV reports {w}x{h} with {n} frames; re-encode the video")
    return w, h, n


def load_n3dv(path, max_frames: int | None = None, resolution_scale: float = 1.0,
              background=(1.0, 1.0, 1.0)) -> Scene:
    """poses_bounds.npy rows are cameras in the order cam00, cam01, ...; all frames share one clip length."""
    from gsgs_engine.cameras import cameras_from_llff
    from gsgs_engine.io.images import ImageLoader, image_info

    root = Path(path)
    poses_path = root / "poses_bounds.npy"
    try:
        array = np.load(poses_path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise GsgsError(f"{poses_path}: cannot read it as a NumPy array ({exc}); regenerate it") from exc
    sources = _camera_sources(root)
    if not sources:
        raise GsgsError(f"{root}: no cam00.mp4 ... videos or cam00/ ... frame folders next to poses_bounds.npy")
    if array.ndim != 2 or len(array) != len(sources):
        raise GsgsError(f"{poses_path}: {len(array) if array.ndim == 2 else '?'} poses but {len(sources)} cameras "
                        f"({sources[0].name} ...); keep one row per camera, in camera order")
    per_cam = []  # (size, [(frame id, loader factory)], frame count)
    for src in sources:
        if src.is_file():
            w, h, n = video_info(src)
            per_cam.append(((w, h), n, src))
        else:
            files = _frame_files(src)
            if not files:
                raise GsgsError(f"{src}: no frame images; put cam folders' frames as PNG/JPEG files")
            info = image_info(files[0])
            per_cam.append(((info.width, info.height), len(files), files))
    # N3DV videos differ by a frame or two at the end; the common prefix is the synchronised part.
    total = min(n for _, n, _ in per_cam)
    frames = pick_frames(total, max_frames, str(root))
    times = frame_times(frames, total)
    bg = np.asarray(background, dtype=np.float32).reshape(3)
    views = []
    for ci, (src, ((w, h), _, media)) in enumerate(zip(sources, per_cam)):
        base = cameras_from_llff(array[ci:ci + 1], (w, h), names=[src.stem], source=str(poses_path))[0]
        if resolution_scale != 1.0:
            base = base.scaled(resolution_scale)
        size = (base.width, base.height)
        for f, t in zip(frames, times):
            cam = replace(base, name=f"{src.stem}/{f:04d}", time=float(t),
                          extra={"camera_index": ci, "frame": int(f)})
            if isinstance(media, list):
                view = View(camera=cam, image_path=media[f], background=bg, loader=ImageLoader(media[f], size))
            else:
                view = View(camera=cam, image_path=media, background=bg, loader=VideoFrameLoader(media, f, size))
            views.append(view)
    bounds = array[:, 15:17]
    all_idx = list(range(len(views)))
    return Scene(views=views, splits={"train": all_idx, "test": []}, source=str(root), format="n3dv",
                 background=bg, near=float(bounds.min()), far=float(bounds.max()), has_alpha=False)


# -- NeRF-synthetic with time (D-NeRF style, or this project's Blender renders) ----------------------
def load_nerf_with_time(path, max_frames: int | None = None, resolution_scale: float = 1.0,
                        background=(1.0, 1.0, 1.0)) -> Scene:
    """load_nerf_synthetic plus each frame's "time" (normalised to [0, 1]) and camera grouping."""
    from gsgs_engine.io.nerf_synthetic import load_nerf_synthetic, transforms_files

    root = Path(path)
    scene = load_nerf_synthetic(root, resolution_scale=resolution_scale, background=background)
    files = transforms_files(root)
    frames = []
    for json_path in files.values():  # the same file and frame order as load_nerf_synthetic's views
        for i, fr in enumerate(json.loads(json_path.read_text())["frames"]):
            if "time" not in fr:
                raise GsgsError(f"{json_path} frame {i}: no \"time\"; a dynamic scene needs a time on every frame "
                                "(or none at all for a static scene)")
            try:
                t = float(fr["time"])
            except (TypeError, ValueError) as exc:
                raise GsgsError(f"{json_path} frame {i}: time {fr['time']!r} is not a number") from exc
            if not np.isfinite(t):
                raise GsgsError(f"{json_path} frame {i}: time is not finite")
            frames.append((fr, t))
    if len(frames) != len(scene.views):
        raise GsgsError(f"{root}: {len(frames)} frames in the JSON files but {len(scene.views)} views loaded")
    raw = np.array([t for _, t in frames])
    lo, hi = float(raw.min()), float(raw.max())
    norm = np.zeros_like(raw) if hi <= lo else (raw - lo) / (hi - lo)
    keys = [_camera_key(fr) for fr, _ in frames]
    order = sorted(set(keys), key=_natural_key)
    cam_of = {k: i for i, k in enumerate(order)}
    distinct = sorted(set(np.round(norm, 9).tolist()))
    keep_times = set(distinct[i] for i in pick_frames(len(distinct), max_frames, str(root)))
    frame_of = {t: i for i, t in enumerate(distinct)}
    keep = []
    for idx, (view, key, t) in enumerate(zip(scene.views, keys, norm)):
        tr = round(float(t), 9)
        view.camera = replace(view.camera, time=float(t),
                              extra={**view.camera.extra, "camera_index": cam_of[key], "frame": frame_of[tr]})
        if tr in keep_times:
            keep.append(idx)
    if len(keep) != len(scene.views):
        remap = {old: new for new, old in enumerate(keep)}
        scene.views = [scene.views[i] for i in keep]
        scene.splits = {k: [remap[i] for i in v if i in remap] for k, v in scene.splits.items()}
    scene.format = "blender+time"
    return scene


def _camera_key(frame: dict) -> str:
    if "camera_id" in frame:
        return f"id:{frame['camera_id']}"
    if "camera_name" in frame:
        return str(frame["camera_name"])
    m = np.round(np.asarray(frame["transform_matrix"], dtype=np.float64), 6)
    return "pose:" + ",".join(f"{x:.6f}" for x in m.reshape(-1))


def _natural_key(s: str):
    return [int(p) if p.isdigit() else p for p in re.split(r"(\d+)", s)]
