"""`gsgs sfm PHOTOS --out DIR`: photos -> COLMAP folder (undistorted images, sparse/0, report)."""

from __future__ import annotations

import argparse
import sys
import time

from gsgs_engine.sfm import CAMERA_MODELS


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("photos", help="folder of overlapping photos (jpg, png, tif, bmp, webp, heic; "
                                       "turned upright by their EXIF orientation)")
    parser.add_argument("--out", required=True, help="output folder: images/, sparse/0/, sfm_report.json")
    parser.add_argument("--camera-model", default="SIMPLE_RADIAL", choices=CAMERA_MODELS, metavar="MODEL",
                        help="COLMAP camera model to calibrate (default SIMPLE_RADIAL; "
                             f"one of {', '.join(CAMERA_MODELS)})")
    parser.add_argument("--max-image-size", type=int, default=1600,
                        help="larger photos are downscaled once to this longest side, used for features and the "
                             "undistorted images (default 1600)")
    parser.add_argument("--per-image-cameras", action="store_true",
                        help="calibrate each photo's intrinsics separately (photos from different cameras or zoom)")


def run(args: argparse.Namespace) -> int:
    from gsgs_engine.sfm import SfmFailed, run_sfm

    started = time.time()

    def show(stage: str, step: int, total: int, message: str) -> None:
        print(f"[{step + 1}/{total}] {message} ({time.time() - started:.0f} s)", flush=True)

    try:
        result = run_sfm(args.photos, args.out, camera_model=args.camera_model,
                         single_camera=not args.per_image_cameras, max_image_size=args.max_image_size,
                         progress=show)
    except SfmFailed as exc:
        registered = sum(v.registered for v in exc.views)
        print(f"registered {registered}/{len(exc.views)} views")
        for v in exc.views:
            if not v.registered:
                print(f"  {v.name}: {v.reason}")
        print(f"gsgs: {exc}", file=sys.stderr)
        return 1
    print(result.summary())
    print(f"  {result.strategy_line()}")
    for v in result.failed:
        print(f"  {v.name}: {v.reason}")
    if result.failed:
        print(f"  retake: {', '.join(v.name for v in result.failed)}")
    for note in result.notes:
        print(f"  note: {note}")
    if result.skipped_files:
        print(f"  skipped (not images): {', '.join(result.skipped_files)}")
    print(f"{len(result.points)} points, mean reprojection error {result.mean_reprojection_error:.2f} px, "
          f"{time.time() - started:.0f} s; COLMAP model in {result.sparse_dir}, report in {result.report_path}")
    return 0 if result.num_registered >= 2 else 1
