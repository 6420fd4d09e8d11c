"""Structure from motion with pycolmap: photos -> cameras + sparse points, and triangulation
from known poses (the sparse-view protocol's initial point cloud, training views only).

Every pycolmap call runs in a spawned child process. pycolmap's extension exports its own
zlib symbols, and any zlib user loaded after it in the same process (cv2.imwrite to PNG,
Pillow, zlib.compress) aborts with a double free; COLMAP also logs verbosely to stderr and
can abort natively on degenerate input. In a child, the log goes to a file, a native crash
becomes a GsgsError naming that file, and a cancel request can stop a long stage at once.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import shutil
import tempfile
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.init import cache as init_cache
from gsgs_engine.io.photos import PHOTO_EXTENSIONS, prepare_photos, scan_photo_folder
from gsgs_engine import sfm_strategies
from gsgs_engine.sfm_strategies import STRATEGIES

log = logging.getLogger(__name__)

# COLMAP camera models whose images pycolmap can undistort to a pinhole camera.
CAMERA_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV",
                 "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "OPENCV_FISHEYE", "FOV", "THIN_PRISM_FISHEYE")
SFM_STAGES = ("features", "matching", "mapping", "undistortion")
TRIANGULATION_STAGES = ("features", "matching", "triangulation")
# Up to this many photos the matcher compares every pair and the mapper uses the
# permissive thresholds below; a larger set is a video or a capture walk (sequential).
SMALL_SET = 30
# pycolmap's SIFT crashes the process (SIGSEGV) on tiny images: measured 16x12 px crashing, 24x18 running
MIN_FEATURE_SIDE = 18
EXHAUSTIVE_LIMIT = 150
# Up to this many photos match on one thread, repeatably (see _child_sfm).
ONE_THREAD_MATCHING = 10

ProgressFn = Callable[[str, int, int, str], None]  # (stage, step, total, message)


# ---------------------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------------------
@dataclass
class ViewReport:
    """What SfM made of one input photo; `reason` says which strategy registered it, or why it
    is missing from the model and what to retake."""

    name: str
    registered: bool
    reason: str = ""
    num_features: int = 0
    num_matched_views: int = 0  # other photos it shares a verified two-view geometry with
    max_inliers: int = 0  # largest verified match count with any other photo
    num_points: int = 0  # 3D points of the chosen model it observes


@dataclass
class SfmResult:
    out_dir: Path
    sparse_dir: Path  # COLMAP model of the undistorted (PINHOLE) images: cameras/images/points3D.bin
    image_dir: Path  # undistorted images named as the input photos
    cameras: list[Camera]  # registered views, in input order; name = image file name
    image_paths: list[Path]
    points: np.ndarray  # (N, 3) float32
    point_colors: np.ndarray  # (N, 3) float32 in [0, 1]
    views: list[ViewReport]  # every input photo, in input order
    skipped_files: list[str]  # files in the folder that are not images
    mean_reprojection_error: float
    report_path: Path
    notes: list[str] = field(default_factory=list)  # adjustments made to the request, for the user
    strategy: str = ""  # the mapping strategy whose model was kept (gsgs_engine.sfm_strategies)
    strategy_reason: str = ""  # why it was kept
    attempts: list[dict] = field(default_factory=list)  # every strategy tried: registered, points, error, s
    photos_note: str = ""  # what was done to the photos as stored (turned, decoded, downscaled); also in notes

    @property
    def num_registered(self) -> int:
        return sum(v.registered for v in self.views)

    @property
    def num_views(self) -> int:
        return len(self.views)

    @property
    def failed(self) -> list[ViewReport]:
        return [v for v in self.views if not v.registered]

    def summary(self) -> str:
        return f"registered {self.num_registered}/{self.num_views} views"

    def strategy_line(self) -> str:
        return f"strategy: {sfm_strategies.describe(self.strategy)}: {self.strategy_reason}"


class SfmFailed(GsgsError):
    """No model could be built; `views` still says what happened to each photo."""

    def __init__(self, message: str, views: list[ViewReport], report_path: Path | None = None):
        super().__init__(message)
        self.views = views
        self.report_path = report_path


@dataclass
class Triangulation:
    """Points triangulated from known poses. `tracks[i]` is a (k, 3) array of
    (view index, u, v) observations of point i, in the input views' pixel coordinates."""

    points: np.ndarray  # (N, 3) float32
    colors: np.ndarray  # (N, 3) float32 in [0, 1]
    errors: np.ndarray  # (N,) mean reprojection error in pixels
    tracks: list[np.ndarray] = field(default_factory=list)
    num_features: list[int] = field(default_factory=list)
    num_verified_matches: int = 0
    reason: str = ""  # why there are no (or few) points, empty when all went well


# ---------------------------------------------------------------------------------------
# Public API
# ---------------------------------------------------------------------------------------
def run_sfm(photo_dir: str | os.PathLike, out_dir: str | os.PathLike, camera_model: str = "SIMPLE_RADIAL",
            single_camera: bool = True, max_image_size: int = 1600, progress: ProgressFn | None = None,
            should_cancel: Callable[[], bool] | None = None, num_threads: int = -1,
            strategies: Sequence[str] = STRATEGIES) -> SfmResult:
    """Recover cameras and sparse points from unposed photos with pycolmap.

    Writes a COLMAP folder: out_dir/images (undistorted), out_dir/sparse/0/*.bin (PINHOLE),
    out_dir/distorted/ (database and raw models) and out_dir/sfm_report.json. Views that do
    not register are reported with a reason; raises SfmFailed when no model at all is built.
    The photos are first turned upright by their EXIF orientation, decoded (HEIC too) and
    downscaled to `max_image_size` on their longest side, once, into out_dir/photos_upright
    (gsgs_engine.io.photos.prepare_photos; the report's "photos" says what was done to each):
    SfM, and so the cameras and the undistorted images everything else reads, see those.
    `strategies`: which mapping strategies may run (gsgs_engine.sfm_strategies; all by default);
    the report names the one kept and every attempt. Same photos and settings, same cameras.
    """
    photo_dir = Path(photo_dir)
    out_dir = Path(out_dir)
    if camera_model not in CAMERA_MODELS:
        raise GsgsError(f"camera model {camera_model!r} is not supported; use one of {', '.join(CAMERA_MODELS)}")
    if int(max_image_size) < 64:
        raise GsgsError(f"max_image_size {max_image_size} is too small; use at least 64 (1600 is a good default)")
    unknown = sorted(set(strategies) - set(STRATEGIES))
    if unknown or not strategies:
        raise GsgsError(f"SfM strategies {unknown or 'none'}: choose one or more of {', '.join(STRATEGIES)}")
    sources, _, unsupported = scan_photo_folder(photo_dir)
    notes = [f"skipped {line}" for line in unsupported]
    if len(sources) < 2:
        raise GsgsError(f"{photo_dir}: found {len(sources)} image(s); structure from motion needs at least 2 "
                        f"overlapping photos ({', '.join(PHOTO_EXTENSIONS)})"
                        + (f"; {'; '.join(notes)}" if notes else ""))
    _prepare_out_dir(out_dir, photo_dir)
    # Photos as stored -> upright copies at the working size: what every later stage reads.
    prepared = prepare_photos(photo_dir, out_dir / UPRIGHT_DIR, max_image_size)
    names, skipped, sizes = prepared.names, prepared.skipped, prepared.sizes
    if prepared.summary():
        notes.append(prepared.summary())
        log.info("%s: %s", photo_dir, notes[-1])
    if single_camera and len(set(sizes.values())) > 1:
        # COLMAP refuses every photo whose size differs from the first under one shared camera.
        single_camera = False
        notes.append(f"the photos have {len(set(sizes.values()))} different sizes, so each photo got its own camera")
        log.info("%s: %s", photo_dir, notes[-1])
    params = {"photo_dir": str(prepared.folder.resolve()), "names": names, "out_dir": str(out_dir.resolve()),
              "camera_model": camera_model, "single_camera": bool(single_camera),
              "max_image_size": int(max_image_size), "num_threads": int(num_threads),
              "strategies": [s for s in STRATEGIES if s in strategies]}
    log_path = out_dir / "colmap.log"
    started = time.time()
    raw = _run_in_child("sfm", params, log_path, SFM_STAGES, progress, should_cancel)
    views = [ViewReport(**v) for v in raw["views"]]
    notes += raw["notes"]
    report = {"photo_dir": str(photo_dir), "registered": sum(v.registered for v in views), "total": len(views),
              "strategy": raw["strategy"], "strategy_reason": raw["strategy_reason"], "attempts": raw["attempts"],
              "retake": [v.name for v in views if not v.registered],
              "camera_model": camera_model, "single_camera": bool(raw["single_camera"]),
              "max_image_size": int(max_image_size), "models": raw["model_sizes"],
              "num_points": int(len(raw.get("points", ()))),
              "mean_reprojection_error": raw.get("mean_reprojection_error"),
              "seconds": round(time.time() - started, 2), "skipped_files": skipped,
              "unsupported_files": prepared.unsupported, "notes": notes,
              "working_photos": str(prepared.folder), "photos": [p.to_dict() for p in prepared.photos],
              "views": [asdict(v) for v in views], "log": str(log_path)}
    report_path = out_dir / "sfm_report.json"
    report_path.write_text(json.dumps(report, indent=2))
    if not raw["model_sizes"]:
        tried = ", ".join(a["strategy"] for a in raw["attempts"]) or "none"
        raise SfmFailed(f"{photo_dir}: no reconstruction could be built from {len(names)} photos "
                        f"({_failure_digest(views)}; strategies tried: {tried}); take more photos with more overlap (60-80% between "
                        "neighbours), move the camera between shots rather than only rotating it, "
                        "and avoid blank or blurry frames", views, report_path)
    cameras, image_paths = [], []
    for entry in raw["cameras"]:
        cameras.append(Camera(R=np.array(entry["R"]), t=np.array(entry["t"]), fx=entry["fx"], fy=entry["fy"],
                              cx=entry["cx"], cy=entry["cy"], width=entry["width"], height=entry["height"],
                              name=entry["name"]).validate(str(out_dir / "sparse" / "0")))
        image_paths.append(out_dir / "images" / entry["name"])
    return SfmResult(out_dir=out_dir, sparse_dir=out_dir / "sparse" / "0", image_dir=out_dir / "images",
                     cameras=cameras, image_paths=image_paths,
                     points=np.asarray(raw["points"], dtype=np.float32).reshape(-1, 3),
                     point_colors=np.asarray(raw["colors"], dtype=np.float32).reshape(-1, 3),
                     views=views, skipped_files=skipped,
                     mean_reprojection_error=float(raw["mean_reprojection_error"]), report_path=report_path,
                     notes=notes, strategy=raw["strategy"], strategy_reason=raw["strategy_reason"],
                     attempts=raw["attempts"], photos_note=prepared.summary())


def triangulate_known_poses(views, out_dir: str | os.PathLike | None = None,
                            **options) -> tuple[np.ndarray, np.ndarray]:
    """Sparse points (N, 3) and colours (N, 3) in [0, 1] from views with KNOWN poses.

    `views`: gsgs_engine.io.scene.View objects (RGBA is composited by View.image()) or
    (Camera, image HxWx3 float in [0, 1]) pairs. Pass only the training views of a sparse-view
    benchmark. Returns empty arrays, with a logged reason, when the views do not match.
    Options: see triangulate_with_known_poses.
    """
    result = triangulate_with_known_poses(views, out_dir=out_dir, **options)
    return result.points, result.colors


def triangulate_with_known_poses(views, out_dir: str | os.PathLike | None = None, max_image_size: int = 1600,
                                 max_epipolar_error: float = 2.0, max_reprojection_error: float = 2.0,
                                 min_triangulation_angle: float = 1.5, max_ratio: float = 0.85,
                                 progress: ProgressFn | None = None,
                                 should_cancel: Callable[[], bool] | None = None) -> Triangulation:
    """triangulate_known_poses with the details: per-point errors and tracks, feature counts.

    Matches are verified with the epipolar geometry the known poses imply (Sampson distance
    below `max_epipolar_error` px) instead of RANSAC: sparse views far apart give too few
    matches for a robust estimate, but the true geometry needs no estimate. `out_dir` keeps
    the images, database and triangulated COLMAP model (a temporary folder otherwise).
    """
    pairs = _as_camera_image_pairs(views)
    if len(pairs) < 2:
        return _empty_triangulation(f"{len(pairs)} view(s) given; triangulation needs at least 2")
    small = min(min(cam.width, cam.height) for cam, _ in pairs)
    if small < MIN_FEATURE_SIDE:
        return _empty_triangulation(f"images {small} px on their shorter side are too small for SIFT features "
                                    f"(at least {MIN_FEATURE_SIDE} px); train at a larger size for a triangulated "
                                    "initialisation")
    work = Path(out_dir) if out_dir is not None else Path(tempfile.mkdtemp(prefix="gsgs_triangulate_"))
    try:
        image_dir = work / "images"
        if image_dir.exists():
            shutil.rmtree(image_dir)
        image_dir.mkdir(parents=True)
        for stale in ("database.db", "database.db-shm", "database.db-wal", "sparse"):
            _remove(work / stale)
        entries = []
        for i, (cam, img) in enumerate(pairs):
            name = f"{i:04d}.png"
            _write_png(image_dir / name, img)
            entries.append({"name": name, "R": cam.R.tolist(), "t": cam.t.tolist(), "fx": cam.fx, "fy": cam.fy,
                            "cx": cam.cx, "cy": cam.cy, "width": cam.width, "height": cam.height})
        params = {"work": str(work.resolve()), "entries": entries, "max_image_size": int(max_image_size),
                  "max_epipolar_error": float(max_epipolar_error),
                  "max_reprojection_error": float(max_reprojection_error),
                  "min_triangulation_angle": float(min_triangulation_angle), "max_ratio": float(max_ratio)}
        # out_dir asks for the COLMAP files themselves: only a temporary folder's run is served from the cache
        digest = _triangulation_key(params, [image_dir / e["name"] for e in entries]) if out_dir is None else None
        raw = init_cache.load_json("triangulation", digest) if digest is not None else None
        if raw is not None:
            log.info("triangulation of %d known poses: reused (init cache %s)", len(pairs), digest[:12])
            if progress is not None:
                progress("triangulation", len(TRIANGULATION_STAGES) - 1, len(TRIANGULATION_STAGES),
                         "reused the triangulation of these views from an earlier run (init cache)")
        else:
            raw = _run_in_child("triangulate", params, work / "colmap.log", TRIANGULATION_STAGES, progress,
                                should_cancel)
            if digest is not None:
                init_cache.store_json("triangulation", digest, raw)
    finally:
        if out_dir is None:
            shutil.rmtree(work, ignore_errors=True)
    result = Triangulation(points=np.asarray(raw["points"], dtype=np.float32).reshape(-1, 3),
                           colors=np.asarray(raw["colors"], dtype=np.float32).reshape(-1, 3),
                           errors=np.asarray(raw["errors"], dtype=np.float64).reshape(-1),
                           tracks=[np.asarray(t, dtype=np.float64).reshape(-1, 3) for t in raw["tracks"]],
                           num_features=list(raw["num_features"]),
                           num_verified_matches=int(raw["num_verified_matches"]), reason=raw["reason"])
    if result.reason:
        log.warning("triangulation from %d known poses: %s", len(pairs), result.reason)
    return result


def _triangulation_key(params: dict, image_files: list[Path]) -> str:
    """The init cache's key of a triangulation: what the child reads (the PNGs as written, the cameras and
    thresholds; not the temporary folder), the processor count (pycolmap's threads), this module's code and
    pycolmap's version."""
    return init_cache.key("triangulation", {k: v for k, v in params.items() if k != "work"}, os.cpu_count(),
                          [init_cache.key(f.read_bytes()) for f in image_files],
                          init_cache.source_digest(__name__, sfm_strategies.__name__),
                          init_cache.package_versions("pycolmap", "numpy"))


def run_sfm_job(job) -> SfmResult:
    """Job task "sfm": job.spec["data"]["photos"] -> COLMAP folder in job.result_dir, plus
    result/cameras.json (Camera.to_dict() + "image") and result/points.ply (xyz + rgb)."""
    from gsgs_engine.settings_schema import SFM, check_section

    data = job.spec.get("data") or {}
    settings = check_section(job.spec.get("settings") or {}, SFM, f"{job.spec_path} settings")
    photos = data.get("photos")
    if not photos:
        raise GsgsError(f"{job.spec_path}: data.photos is missing; set it to the folder of photos to reconstruct")
    photos = Path(photos)
    if not photos.is_absolute():
        photos = (job.root / photos).resolve()
    stages = SFM_STAGES + ("export",)

    def report(stage: str, step: int, total: int, message: str) -> None:
        job.emit("sfm", stages.index(stage) if stage in stages else step, len(stages), message=message,
                 stage=stage)

    try:
        max_image_size = int(settings.get("max_image_size", 1600))
    except (TypeError, ValueError):
        raise GsgsError(f"{job.spec_path}: settings.max_image_size must be a whole number of pixels, "
                        f"not {settings.get('max_image_size')!r}") from None
    result = run_sfm(photos, job.result_dir, camera_model=settings.get("camera_model", "SIMPLE_RADIAL"),
                     single_camera=bool(settings.get("single_camera", True)), max_image_size=max_image_size,
                     progress=report, should_cancel=job.cancel_requested)
    if job.cancel_requested():
        raise KeyboardInterrupt
    report("export", 0, 0, "writing cameras.json and points.ply")
    write_cameras_json(job.result_dir / "cameras.json", result.cameras, result.image_paths)
    write_point_ply(job.result_dir / "points.ply", result.points, result.point_colors)
    failed = "; ".join(f"{v.name}: {v.reason}" for v in result.failed)
    job.emit("sfm", len(stages), len(stages), message=result.summary() + (f" ({failed})" if failed else "")
             + (f"; {result.photos_note}" if result.photos_note else ""),
             stage="done", registered=result.num_registered, total_views=result.num_views)
    if result.num_registered < 2:
        raise GsgsError(f"{photos}: {result.summary()}; add photos that overlap more")
    job.set_status("ok", f"{result.summary()} ({result.strategy})" + (f"; retake: {failed}" if failed else ""))
    return result


# ---------------------------------------------------------------------------------------
# Plain files (numpy only, no pycolmap)
# ---------------------------------------------------------------------------------------
def write_cameras_json(path: Path, cameras: Sequence[Camera], image_paths: Sequence[Path]) -> None:
    entries = [{**cam.to_dict(), "image": str(Path(p).resolve())} for cam, p in zip(cameras, image_paths)]
    Path(path).write_text(json.dumps(entries, indent=2))


def write_point_ply(path: Path, points: np.ndarray, colors: np.ndarray) -> None:
    """Plain binary little-endian PLY: x y z (float32) red green blue (uchar)."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    rgb = np.clip(np.round(np.asarray(colors, dtype=np.float64).reshape(-1, 3) * 255.0), 0, 255).astype(np.uint8)
    if len(rgb) != len(points):
        raise ValueError(f"{len(points)} points but {len(rgb)} colours")
    vertex = np.empty(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                          ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    vertex["x"], vertex["y"], vertex["z"] = points.T
    vertex["red"], vertex["green"], vertex["blue"] = rgb.T
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(points)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(vertex.tobytes())


def _as_camera_image_pairs(views) -> list[tuple[Camera, np.ndarray]]:
    pairs = []
    for i, item in enumerate(views):
        if isinstance(item, tuple) and len(item) == 2:
            cam, img = item
            img = np.asarray(img)
            if img.dtype == np.uint8:
                img = img.astype(np.float32) / 255.0
            if img.ndim == 3 and img.shape[2] == 4:  # composite on white, as View.image() does
                img = img[..., :3] * img[..., 3:4] + (1.0 - img[..., 3:4])
        else:
            cam, img = item.camera, item.image()
        if img.ndim != 3 or img.shape[2] != 3:
            raise GsgsError(f"view {i} ({cam.name}): expected an HxWx3 image, got shape {img.shape}")
        if (img.shape[1], img.shape[0]) != (cam.width, cam.height):
            raise GsgsError(f"view {i} ({cam.name}): image is {img.shape[1]}x{img.shape[0]} but the camera "
                            f"expects {cam.width}x{cam.height}; resize the image or fix the intrinsics")
        pairs.append((cam.validate(f"view {i}"), img))
    return pairs


def _write_png(path: Path, img: np.ndarray) -> None:
    import cv2  # safe: this process never loads pycolmap (see module docstring)

    arr = np.asarray(img)
    if arr.dtype != np.uint8:
        arr = np.clip(np.round(arr.astype(np.float64) * 255.0), 0, 255).astype(np.uint8)
    if not cv2.imwrite(str(path), cv2.cvtColor(arr, cv2.COLOR_RGB2BGR)):
        raise GsgsError(f"{path}: could not write the image; check the folder is writable and has free space")


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


UPRIGHT_DIR = "photos_upright"  # the photos turned upright and downscaled once (gsgs_engine.io.photos)
_SFM_OUTPUTS = (UPRIGHT_DIR, "distorted", "sparse", "images", "stereo", "sfm_report.json", "colmap.log",
                "run-colmap-geometric.sh", "run-colmap-photometric.sh")
_SFM_MARKER = ".gsgs_sfm"


def _prepare_out_dir(out_dir: Path, photo_dir: Path) -> None:
    """Clear a previous run's outputs (a rerun must not mix models) but never anything else:
    outputs are removed only from a folder this function marked as an SfM output folder."""
    photos, out = photo_dir.resolve(), out_dir.resolve()
    if photos == out or any(photos == out / name or out / name in photos.parents for name in _SFM_OUTPUTS):
        raise GsgsError(f"{out_dir}: the output folder would overwrite the photos in {photo_dir}; "
                        "choose another --out folder, e.g. a sibling of the photo folder")
    existing = [name for name in _SFM_OUTPUTS if (out_dir / name).exists()]
    if existing and not (out_dir / _SFM_MARKER).exists():
        raise GsgsError(f"{out_dir}: already holds {', '.join(existing)} not written by gsgs sfm; "
                        "choose an empty output folder")
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / _SFM_MARKER).write_text("written by gsgs sfm; its outputs here are replaced on the next run\n")
    for name in existing:
        _remove(out_dir / name)


def _empty_triangulation(reason: str) -> Triangulation:
    log.warning("triangulation from known poses: %s", reason)
    return Triangulation(points=np.zeros((0, 3), np.float32), colors=np.zeros((0, 3), np.float32),
                         errors=np.zeros(0), reason=reason)


def _failure_digest(views: list[ViewReport]) -> str:
    reasons = [f"{v.name}: {v.reason.split(':')[0]}" for v in views if not v.registered]
    return "; ".join(reasons) if reasons else "no view registered"


# ---------------------------------------------------------------------------------------
# Child process
# ---------------------------------------------------------------------------------------
def _run_in_child(task: str, params: dict, log_path: Path, stages: Sequence[str], progress: ProgressFn | None,
                  should_cancel: Callable[[], bool] | None) -> dict:
    """Run _TASKS[task](params) in a spawned process, relaying stage messages to `progress`."""
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    ctx = multiprocessing.get_context("spawn")
    recv_end, send_end = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_child_main, args=(send_end, task, params, str(log_path)), daemon=True)
    proc.start()
    send_end.close()  # so recv() sees EOF when the child dies
    stage = "start"
    try:
        while True:
            if should_cancel is not None and should_cancel():
                raise KeyboardInterrupt
            if not recv_end.poll(0.2):
                if not proc.is_alive() and not recv_end.poll(0):
                    break
                continue
            try:
                kind, payload = recv_end.recv()
            except EOFError:
                break
            if kind == "stage":
                stage = payload["stage"]
                if progress is not None:
                    step = stages.index(stage) if stage in stages else 0
                    progress(stage, step, len(stages), payload["message"])
            elif kind == "done":
                proc.join()
                return payload
            elif kind == "gsgs_error":
                proc.join()
                raise GsgsError(payload)
            elif kind == "error":
                proc.join()
                with open(log_path, "a") as fh:
                    fh.write(payload)
                last = payload.strip().splitlines()[-1]
                raise GsgsError(f"pycolmap failed during {stage}: {last} (details in {log_path})")
    finally:
        if proc.is_alive():
            proc.terminate()
            proc.join(5)
            if proc.is_alive():
                proc.kill()
                proc.join()
        recv_end.close()
    proc.join()
    raise GsgsError(f"pycolmap stopped unexpectedly (exit code {proc.exitcode}) during {stage}; "
                    f"last log line: {_last_line(log_path)!r} (full log: {log_path})")


def _last_line(path: Path) -> str:
    try:
        lines = [ln for ln in Path(path).read_text(errors="replace").splitlines() if ln.strip()]
    except OSError:
        return ""
    return lines[-1][-200:] if lines else ""


def _child_main(conn, task: str, params: dict, log_path: str) -> None:
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)

    def emit(stage: str, message: str) -> None:
        print(f"== gsgs stage {stage}: {message}", flush=True)
        conn.send(("stage", {"stage": stage, "message": message}))

    try:
        import zlib  # noqa: F401  -- bind the system zlib before pycolmap's copy (module docstring)

        import pycolmap

        pycolmap.set_random_seed(0)  # same photos, same model
        result = _TASKS[task](pycolmap, params, emit)
    except GsgsError as exc:
        conn.send(("gsgs_error", str(exc)))
    except BaseException:  # noqa: BLE001 -- everything must reach the parent as text
        conn.send(("error", traceback.format_exc()))
    else:
        conn.send(("done", result))
    finally:
        conn.close()


def _child_sfm(pycolmap, p: dict, emit) -> dict:
    photo_dir, out_dir, names = Path(p["photo_dir"]), Path(p["out_dir"]), p["names"]
    distorted = out_dir / "distorted"
    distorted.mkdir(parents=True, exist_ok=True)
    db_path = distorted / "database.db"
    small = len(names) <= SMALL_SET
    device = pycolmap.Device.cpu if not pycolmap.has_cuda else pycolmap.Device.auto
    notes = []
    single_camera = p["single_camera"]
    fix_focal = False
    if single_camera:
        cameras_seen, focals = _exif_cameras(pycolmap, photo_dir, names)
        if len(cameras_seen) > 1:
            single_camera = False
            notes.append(f"the photos' EXIF names {len(cameras_seen)} different cameras or focal lengths "
                         f"({'; '.join(sorted(cameras_seen))}), so each photo got its own camera")
        elif small and len(focals) == len(names):
            # A few photos close together barely constrain the focal length: refined, it drifts
            # (flower frames 15-17: 2 degrees and 15% of the rig off); the camera's own is better.
            fix_focal = True
            notes.append(f"focal length {focals[0]:.0f} px from the photos' EXIF kept fixed "
                         f"({len(names)} photos barely constrain it)")

    emit("features", f"extracting SIFT features from {len(names)} photos (longest side {p['max_image_size']} px)")
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = p["camera_model"]
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = p["max_image_size"]
    extraction.num_threads = p["num_threads"]
    mode = pycolmap.CameraMode.SINGLE if single_camera else pycolmap.CameraMode.PER_IMAGE
    # Image ids in name order: threaded extraction would number photos as they finish, and the
    # mappers visit photos by id, so the same photos could give different cameras run to run.
    pycolmap.Database.open(db_path).close()
    pycolmap.import_images(db_path, photo_dir, camera_mode=mode, image_names=names, options=reader)
    pycolmap.extract_features(db_path, photo_dir, image_names=names, camera_mode=mode, reader_options=reader,
                              extraction_options=extraction, device=device)

    matching = pycolmap.FeatureMatchingOptions()
    # A few photos match on one thread: COLMAP's maintainers give the matcher as repeatable only
    # on one thread (colmap issue 727), and a 3-photo solve is sensitive: one CI run solved the
    # same pixels 1.2 degrees away from every other run (not reproduced in 20 runs since).
    # One thread costs 0.7 -> 1.0 s on 3 photos; larger sets keep every thread (pairs grow with the square).
    matching.num_threads = 1 if len(names) <= ONE_THREAD_MATCHING else p["num_threads"]
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = sfm_strategies.SEED  # each pair's RANSAC seeded: any thread order
    if small:
        verification.min_num_inliers = 10
    if len(names) <= EXHAUSTIVE_LIMIT:
        emit("matching", f"matching all {len(names) * (len(names) - 1) // 2} photo pairs")
        pycolmap.match_exhaustive(db_path, matching_options=matching, verification_options=verification,
                                  device=device)
    else:
        emit("matching", f"matching each of {len(names)} photos with its 10 neighbours in name order")
        pycolmap.match_sequential(db_path, matching_options=matching, verification_options=verification,
                                  device=device)

    best, attempts = sfm_strategies.solve(pycolmap, db_path, photo_dir, distorted / "sparse", len(names), small,
                                          verification.min_num_inliers, emit, p["strategies"], fix_focal)
    recs = {a.strategy: pycolmap.Reconstruction(a.model_dir) for a in attempts if a.model_dir}
    views = _view_reports(pycolmap, db_path, names, best, attempts, recs, verification.min_num_inliers)
    solve_info = {"single_camera": single_camera, "notes": notes,
                  "attempts": [a.to_dict() for a in attempts],
                  "strategy": best.strategy if best else "",
                  "strategy_reason": sfm_strategies.why_best(best, attempts, len(names)) if best else ""}
    if best is None:
        return {"model_sizes": [], "views": views, **solve_info}
    model_sizes = [best.registered]

    emit("undistortion", f"undistorting {best.registered} registered photos to a pinhole camera")
    undistort = pycolmap.UndistortCameraOptions()
    undistort.max_image_size = p["max_image_size"]
    best_rec = recs[best.strategy]
    registered_names = [best_rec.image(i).name for i in best_rec.reg_image_ids()]
    pycolmap.undistort_images(out_dir, best.model_dir, photo_dir, image_names=registered_names,
                              output_type="COLMAP", undistort_options=undistort)
    # undistort_images writes sparse/*.bin; the COLMAP layout loaders expect is sparse/0/.
    sparse0 = out_dir / "sparse" / "0"
    sparse0.mkdir(parents=True, exist_ok=True)
    for f in (out_dir / "sparse").iterdir():
        if f.is_file():
            f.replace(sparse0 / f.name)
    for leftover in ("stereo", "run-colmap-geometric.sh", "run-colmap-photometric.sh"):
        _remove(out_dir / leftover)

    rec = pycolmap.Reconstruction(sparse0)
    by_name = {rec.image(i).name: rec.image(i) for i in rec.reg_image_ids()}
    cameras = []
    for name in names:
        image = by_name.get(name)
        if image is None:
            continue
        cam = rec.camera(image.camera_id)
        fx, fy, cx, cy = (float(v) for v in cam.params[:4])  # undistorted cameras are PINHOLE
        pose = image.cam_from_world().matrix()
        cameras.append({"name": name, "R": pose[:, :3].tolist(), "t": pose[:, 3].tolist(), "fx": fx, "fy": fy,
                        "cx": cx, "cy": cy, "width": int(cam.width), "height": int(cam.height)})
    ids = list(rec.point3D_ids())
    points = np.array([rec.point3D(i).xyz for i in ids], dtype=np.float64).reshape(-1, 3)
    colors = np.array([rec.point3D(i).color for i in ids], dtype=np.float64).reshape(-1, 3) / 255.0
    return {"model_sizes": model_sizes, "views": views, "cameras": cameras, "points": points, "colors": colors,
            "mean_reprojection_error": float(rec.compute_mean_reprojection_error()), **solve_info}


def _exif_cameras(pycolmap, photo_dir: Path, names: list[str]) -> tuple[set[str], list[float]]:
    """Distinct 'camera model, focal length' EXIF identities among the photos that carry EXIF,
    and the focal lengths (px) of the photos whose EXIF gives one."""
    seen, focals = set(), []
    for name in names:
        bitmap = pycolmap.Bitmap.read(str(photo_dir / name), False)
        model = bitmap.exif_camera_model() if bitmap is not None else None
        focal = bitmap.exif_focal_length() if bitmap is not None else None
        if focal:
            focals.append(float(focal))
        if model or focal:
            seen.add(f"{model or 'unknown camera'}, focal {focal:.4g}" if focal else f"{model}, focal unknown")
    return seen, focals


def _view_reports(pycolmap, db_path: Path, names: list[str], best, attempts: list, recs: dict,
                  min_inliers: int) -> list[dict]:
    """Why each photo is, or is not, in the chosen model (`best`, an sfm_strategies.Attempt)."""
    chosen = recs.get(best.strategy) if best is not None else None
    seen_in = {}  # name -> 3D points it observes in the chosen model
    if chosen is not None:
        for i in chosen.reg_image_ids():
            seen_in[chosen.image(i).name] = int(chosen.image(i).num_points3D)
    elsewhere: dict[str, list[str]] = {}  # name -> strategies whose (worse) model holds it
    for strategy, rec in recs.items():
        if best is not None and strategy == best.strategy:
            continue
        for i in rec.reg_image_ids():
            elsewhere.setdefault(rec.image(i).name, []).append(f"{strategy} ({rec.num_reg_images()} photos)")
    tried = ", ".join(a.strategy for a in attempts) or "none"
    with pycolmap.Database.open(db_path) as db:
        images = {im.name: im for im in db.read_all_images()}
        id_to_name = {im.image_id: name for name, im in images.items()}
        features = {name: int(db.num_keypoints_for_image(im.image_id)) if db.exists_keypoints(im.image_id) else 0
                    for name, im in images.items()}
        links: dict[str, list[int]] = {name: [] for name in names}
        pair_ids, geometries = db.read_two_view_geometries()
        for pair_id, geom in zip(pair_ids, geometries):
            n = len(geom.inlier_matches)
            if n < min_inliers:
                continue
            for image_id in pycolmap.pair_id_to_image_pair(pair_id):
                links.setdefault(id_to_name[image_id], []).append(n)
    reports = []
    for name in names:
        nf = features.get(name, 0)
        matched = links.get(name, [])
        r = {"name": name, "registered": name in seen_in, "reason": "", "num_features": nf,
             "num_matched_views": len(matched), "max_inliers": max(matched, default=0),
             "num_points": seen_in.get(name, 0)}
        if r["registered"]:
            r["reason"] = (f"registered by {best.strategy}: sees {r['num_points']} of the model's "
                           f"{best.num_points} points")
        elif name not in images:
            r["reason"] = "not read by COLMAP: it skipped this file (reason in colmap.log); convert it to JPEG"
        elif nf == 0:
            r["reason"] = "no features: the image is blank or has no texture; retake it"
        elif not matched:
            r["reason"] = (f"no matches: none of its {nf} features match another photo well enough "
                           "(too little overlap, or too different in viewpoint or lighting); retake it "
                           "closer to its neighbours' viewpoints")
        elif name in elsewhere:
            r["reason"] = (f"not registered: only {', '.join(elsewhere[name])} placed it, in a model that "
                           "left out more photos; retake it, or add a photo between it and the others")
        else:
            r["reason"] = (f"not registered: matched {len(matched)} other photo(s) (best {r['max_inliers']} "
                           f"inliers) but no strategy ({tried}) could estimate its pose (too few matches or "
                           "too small a baseline); retake it with more overlap and a sideways step")
        reports.append(r)
    return reports


def _child_triangulate(pycolmap, p: dict, emit) -> dict:
    work = Path(p["work"])
    image_dir = work / "images"
    db_path = work / "database.db"
    entries = p["entries"]
    emit("features", f"extracting SIFT features from {len(entries)} posed views")
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.max_image_size = p["max_image_size"]
    # Sparse views are far apart: affine-adapted, scale-pooled SIFT matches across larger
    # viewpoint changes, and small renders need the extra upsampled octave to find features.
    extraction.sift.estimate_affine_shape = True
    extraction.sift.domain_size_pooling = True
    if max(max(e["width"], e["height"]) for e in entries) <= 400:
        extraction.sift.first_octave = -2
    names = [e["name"] for e in entries]
    # Image ids in name order (as in _child_sfm): threaded extraction numbers views as they finish, and
    # the triangulator visits views by id, so a busy machine gave other points for the same views.
    pycolmap.Database.open(db_path).close()
    pycolmap.import_images(db_path, image_dir, camera_mode=pycolmap.CameraMode.PER_IMAGE, image_names=names,
                           options=reader)
    pycolmap.extract_features(db_path, image_dir, image_names=names, camera_mode=pycolmap.CameraMode.PER_IMAGE,
                              reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)

    emit("matching", f"matching {len(entries) * (len(entries) - 1) // 2} view pairs, "
                     "verified with the known epipolar geometry")
    matching = pycolmap.FeatureMatchingOptions()
    matching.skip_geometric_verification = True
    matching.sift.max_ratio = p["max_ratio"]
    # One thread for a few views, as _child_sfm does: threaded matching is not repeatable, and the same views
    # triangulated a point or two more or less now and then (a plain lego_200 cell: 172 against 170 Gaussians)
    matching.num_threads = 1 if len(names) <= ONE_THREAD_MATCHING else -1
    pycolmap.match_exhaustive(db_path, matching_options=matching, device=pycolmap.Device.cpu)

    reconstruction = pycolmap.Reconstruction()
    index_of = {}
    with pycolmap.Database.open(db_path) as db:
        db_images = {im.name: im for im in db.read_all_images()}
        num_features = [int(db.num_keypoints_for_image(db_images[n].image_id))
                        if n in db_images and db.exists_keypoints(db_images[n].image_id) else 0 for n in names]
        for k, e in enumerate(entries):
            if e["name"] not in db_images:
                continue
            im = db_images[e["name"]]
            index_of[im.image_id] = k
            cam = pycolmap.Camera(model="PINHOLE", width=e["width"], height=e["height"],
                                  params=[e["fx"], e["fy"], e["cx"], e["cy"]], camera_id=im.camera_id)
            db.update_camera(cam)
            reconstruction.add_camera_with_trivial_rig(cam)
            pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.asarray(e["R"])), np.asarray(e["t"]))
            reconstruction.add_image_with_trivial_frame(
                pycolmap.Image(name=e["name"], camera_id=im.camera_id, image_id=im.image_id), pose)
        keypoints = {i: db.read_keypoints(i)[:, :2].astype(np.float64) for i in index_of if db.exists_keypoints(i)}
        pair_ids, raw_matches = db.read_all_matches()
        verified = 0
        for pair_id, matches in zip(pair_ids, raw_matches):
            id1, id2 = pycolmap.pair_id_to_image_pair(pair_id)
            if id1 not in keypoints or id2 not in keypoints or len(matches) == 0:
                continue
            e1, e2 = entries[index_of[id1]], entries[index_of[id2]]
            F = _fundamental_from_poses(e1, e2)
            err = _sampson_distance(F, keypoints[id1][matches[:, 0]], keypoints[id2][matches[:, 1]])
            inliers = np.ascontiguousarray(matches[err < p["max_epipolar_error"]], dtype=np.uint32)
            if len(inliers) == 0:
                continue
            geometry = pycolmap.TwoViewGeometry()
            geometry.config = pycolmap.TwoViewGeometryConfiguration.CALIBRATED
            geometry.F = F
            geometry.inlier_matches = inliers
            db.write_two_view_geometry(id1, id2, geometry)
            verified += len(inliers)

    empty = {"points": np.zeros((0, 3)), "colors": np.zeros((0, 3)), "errors": np.zeros(0), "tracks": [],
             "num_features": num_features, "num_verified_matches": verified}
    if sum(n > 0 for n in num_features) < 2:
        return {**empty, "reason": f"fewer than 2 views have features (features per view: {num_features}); "
                                   "the images are blank or untextured"}
    if verified == 0:
        return {**empty, "reason": "no feature match agrees with the known camera poses; the views overlap "
                                   "too little (or the poses do not belong to these images)"}

    emit("triangulation", f"triangulating {verified} verified matches")
    options = pycolmap.IncrementalPipelineOptions()
    options.triangulation.ignore_two_view_tracks = False  # few views: most tracks have two
    options.triangulation.min_angle = p["min_triangulation_angle"]
    options.mapper.filter_min_tri_angle = p["min_triangulation_angle"]
    options.mapper.filter_max_reproj_error = p["max_reprojection_error"]
    options.triangulation.random_seed = 0
    sparse = work / "sparse" / "0"
    sparse.mkdir(parents=True, exist_ok=True)
    rec = pycolmap.triangulate_points(reconstruction, db_path, image_dir, sparse, clear_points=True,
                                      options=options, refine_intrinsics=False)
    points, colors, errors, tracks = [], [], [], []
    for pid in rec.point3D_ids():
        pt = rec.point3D(pid)
        if pt.error > p["max_reprojection_error"] or pt.track.length() < 2:
            continue
        points.append(pt.xyz)
        colors.append(np.asarray(pt.color, dtype=np.float64) / 255.0)
        errors.append(pt.error)
        obs = []
        for el in pt.track.elements:
            xy = rec.image(el.image_id).points2D[el.point2D_idx].xy
            obs.append((index_of[el.image_id], xy[0], xy[1]))
        tracks.append(np.array(obs, dtype=np.float64))
    reason = "" if points else ("the verified matches did not triangulate within the angle and "
                                "reprojection limits; the views are too close together or too far apart")
    return {"points": np.array(points, dtype=np.float64).reshape(-1, 3),
            "colors": np.array(colors, dtype=np.float64).reshape(-1, 3), "errors": np.array(errors),
            "tracks": tracks, "num_features": num_features, "num_verified_matches": verified, "reason": reason}


def _fundamental_from_poses(e1: dict, e2: dict) -> np.ndarray:
    """F with x2^T F x1 = 0 for pixel coordinates of the same point in views 1 and 2."""
    R1, t1 = np.asarray(e1["R"]), np.asarray(e1["t"])
    R2, t2 = np.asarray(e2["R"]), np.asarray(e2["t"])
    R = R2 @ R1.T
    t = t2 - R @ t1
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    K1 = np.array([[e1["fx"], 0.0, e1["cx"]], [0.0, e1["fy"], e1["cy"]], [0.0, 0.0, 1.0]])
    K2 = np.array([[e2["fx"], 0.0, e2["cx"]], [0.0, e2["fy"], e2["cy"]], [0.0, 0.0, 1.0]])
    F = np.linalg.inv(K2).T @ tx @ R @ np.linalg.inv(K1)
    return F / np.linalg.norm(F)


def _sampson_distance(F: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """First-order geometric distance (px) of correspondences to the epipolar geometry F."""
    h1 = np.concatenate([x1, np.ones((len(x1), 1))], axis=1)
    h2 = np.concatenate([x2, np.ones((len(x2), 1))], axis=1)
    Fx1 = h1 @ F.T
    Ftx2 = h2 @ F
    num = np.sum(h2 * Fx1, axis=1) ** 2
    den = Fx1[:, 0] ** 2 + Fx1[:, 1] ** 2 + Ftx2[:, 0] ** 2 + Ftx2[:, 1] ** 2
    return np.sqrt(num / np.maximum(den, 1e-300))


_TASKS = {"sfm": _child_sfm, "triangulate": _child_triangulate}
