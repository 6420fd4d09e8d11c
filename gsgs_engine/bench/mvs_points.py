"""`gsgs bench mvs-points`: dense (MVS) initialisation, time and accuracy on the sparse-view protocols' views.

`gsgs bench mvs-points [--data-root ../shared/data] [--scenes llff_flower,...]` prints one JSON line per scene:
- seconds of the MVS itself (SfM triangulation, which the trainer runs anyway, timed apart);
- agreement with the SfM points of the same training views: for each SfM point visible in a training
  view, the nearest MVS depth at its pixel (z-buffer of the fused points) vs the SfM depth;
- NeRF-synthetic only (no ground-truth depth is released): silhouette consistency, the fraction of
  points that land on the object (alpha >= 0.5) in every one of the 25 held-out test views they project
  into. A point off the surface in depth falls outside some silhouette.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
DEFAULT_DATA = REPO.parent / "shared" / "data"
DEFAULT_SCENES = "llff_flower,llff_horns,blender_lego,blender_chair"


def sfm_agreement(points: np.ndarray, sfm: np.ndarray, views) -> dict:
    errs = []
    for v in views:
        c = v.camera
        uv, z = c.project(points.astype(np.float64))
        ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < c.width) & (uv[:, 1] >= 0) & (uv[:, 1] < c.height)
        zbuf = np.full((c.height, c.width), np.inf)
        np.minimum.at(zbuf, (uv[ok, 1].astype(int), uv[ok, 0].astype(int)), z[ok])
        uvs, zs = c.project(sfm.astype(np.float64))
        oks = (zs > 0) & (uvs[:, 0] >= 0) & (uvs[:, 0] < c.width) & (uvs[:, 1] >= 0) & (uvs[:, 1] < c.height)
        zm = zbuf[uvs[oks, 1].astype(int), uvs[oks, 0].astype(int)]
        found = np.isfinite(zm)
        errs.append(np.abs(zm[found] - zs[oks][found]) / zs[oks][found])
    e = np.concatenate(errs) if errs else np.zeros(0)
    if len(e) == 0:
        return {"n": 0}
    return {"n": int(len(e)), "median_rel_err": float(np.median(e)), "within_2pct": float((e < 0.02).mean()),
            "within_5pct": float((e < 0.05).mean())}


def silhouette_consistency(points: np.ndarray, test_views) -> float:
    inside_all = np.ones(len(points), dtype=bool)
    for v in test_views:
        alpha = v.alpha()
        c = v.camera
        uv, z = c.project(points.astype(np.float64))
        ok = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < c.width) & (uv[:, 1] >= 0) & (uv[:, 1] < c.height)
        fg = np.zeros(len(points), dtype=bool)
        fg[ok] = alpha[uv[ok, 1].astype(int), uv[ok, 0].astype(int)] >= 0.5
        inside_all &= fg | ~ok
    return float(inside_all.mean())


def check(name: str, scene, log) -> dict:
    from gsgs_engine.gaussians import scene_bounds_from_cameras
    from gsgs_engine.init.mvs import dense_points
    from gsgs_engine.sfm import triangulate_known_poses

    t0 = time.perf_counter()
    sfm, _ = triangulate_known_poses(scene.train)
    sfm = np.asarray(sfm, dtype=np.float32).reshape(-1, 3)
    t_sfm = time.perf_counter() - t0
    bounds = scene_bounds_from_cameras([v.camera for v in scene.train], scene.near, scene.far)
    t0 = time.perf_counter()
    dense = dense_points(scene.train, sparse_points=sfm if len(sfm) else None, near=scene.near, far=scene.far,
                         bounds=bounds, log=log)
    t_mvs = time.perf_counter() - t0
    first = scene.train[0].camera
    row = {"scene": name, "views": len(scene.train), "size": [first.width, first.height],
           "work_size": dense.stats["views"][0]["size"] if dense.stats["views"] else None,
           "sfm_seconds": round(t_sfm, 1), "mvs_seconds": round(t_mvs, 1), "sfm_points": int(len(sfm)),
           "mvs_points": int(len(dense.points)), "method": dense.method,
           "vs_sfm": sfm_agreement(dense.points, sfm, scene.train) if len(sfm) else None}
    if scene.has_alpha:
        row["silhouette_consistent_mvs"] = silhouette_consistency(dense.points, scene.test)
        row["silhouette_consistent_sfm"] = silhouette_consistency(sfm, scene.test) if len(sfm) else None
    return row


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--data-root", type=Path, default=DEFAULT_DATA,
                        help=f"folder holding the scenes (default {DEFAULT_DATA})")
    parser.add_argument("--scenes", default=DEFAULT_SCENES,
                        help=f"comma-separated scene folders under --data-root (default {DEFAULT_SCENES}); "
                             "llff_*: 3 training views, others: the NeRF-synthetic 8 views at half size")


def run(args: argparse.Namespace) -> int:
    from gsgs_engine import GsgsError

    names = [n.strip() for n in args.scenes.split(",") if n.strip()]
    if not names:
        raise GsgsError("--scenes names no scene; give comma-separated folders under --data-root")
    missing = [n for n in names if not (args.data_root / n).is_dir()]
    if missing:  # before the first scene's minutes, not after them
        raise GsgsError(f"{args.data_root}: no scene folder {', '.join(missing)}; pass --data-root or --scenes")
    import torch

    from gsgs_engine.bench.sparse import BLENDER_TRAIN_IDS
    from gsgs_engine.io.loader import load_scene

    torch.set_num_threads(2)
    for name in names:
        if name.startswith("llff"):
            scene = load_scene(args.data_root / name, train_views=3)
        else:
            scene = load_scene(args.data_root / name, train_ids=BLENDER_TRAIN_IDS, resolution_scale=0.5)
        print(json.dumps(check(name, scene, log=lambda m: None)), flush=True)
    return 0
