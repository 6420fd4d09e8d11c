#!/usr/bin/env python
"""Import cost of a large splat PLY in Blender and what the viewport level of detail costs.

    python scripts/bench_blender_import.py [--count 1000000] [--degree 3] [--ply FILE] [--json OUT]

Writes a synthetic Gaussian PLY of --count splats (or reads --ply), imports it with the add-on
(gsgs_blender.splat_import), and reports: import seconds, peak resident memory of this process,
and the geometry-nodes evaluation time and splat count of the viewport (the default Viewport
Splats cap: the most visible first) and of a render-mode evaluation (every splat, camera planes).
bpy only (no torch); run it under `flock /tmp/gsgs_heavy.lock` on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def synthetic_ply(path: Path, n: int, degree: int, seed: int = 0) -> None:
    from gsgs_engine.io.ply import GaussianPly, write_gaussian_ply

    rng = np.random.default_rng(seed)
    rest = (degree + 1) ** 2 - 1
    write_gaussian_ply(path, GaussianPly(
        positions=rng.normal(size=(n, 3)).astype(np.float32), opacity_logits=rng.normal(size=n).astype(np.float32),
        log_scales=(rng.normal(size=(n, 3)) - 4).astype(np.float32),
        quats_wxyz=rng.normal(size=(n, 4)).astype(np.float32), sh_dc=rng.normal(size=(n, 3)).astype(np.float32),
        sh_rest=(rng.normal(size=(n, rest, 3)) * 0.1).astype(np.float32)))


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def evaluate(obj) -> tuple[float, int]:
    import bpy

    obj.update_tag()
    t0 = time.perf_counter()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    geometry = obj.evaluated_get(depsgraph).evaluated_geometry()
    count = len(geometry.instances_pointcloud().points)
    return time.perf_counter() - t0, count


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--count", type=int, default=1_000_000)
    p.add_argument("--degree", type=int, default=3, choices=(0, 1, 2, 3))
    p.add_argument("--ply", default=None, help="import this PLY instead of a synthetic one")
    p.add_argument("--json", default=None, help="write the figures here too")
    args = p.parse_args(argv)

    import bpy

    from gsgs_blender import camera_convert, node_groups, splat_import
    from gsgs_engine.cameras import Camera, look_at

    bpy.ops.wm.read_factory_settings(use_empty=True)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(args.ply) if args.ply else Path(tmp) / "splats.ply"
        if not args.ply:
            t0 = time.perf_counter()
            synthetic_ply(path, args.count, args.degree)
            print(f"wrote {args.count:,} synthetic splats (SH {args.degree}) in {time.perf_counter() - t0:.1f} s")
        rss_before = peak_rss_mib()
        obj, seconds = splat_import.import_splats(path)
        rss_import = peak_rss_mib()
    scene = bpy.context.scene
    R, t = look_at(np.array([0.0, -6.0, 1.0]), np.zeros(3))
    cam = Camera(R=R, t=t, fx=800, fy=800, cx=480, cy=270, width=960, height=540, name="bench")
    cam_obj = camera_convert.new_camera_object(cam, scene.collection, scene)
    camera_convert.apply_camera_to_object(cam, cam_obj, scene, set_scene_frame=True)
    scene.camera = cam_obj
    mod = obj.modifiers[node_groups.MODIFIER_NAME]
    n = int(obj["gsgs_count"])
    # The bpy module evaluates as the viewport does: the level of detail applies.
    viewport_s, viewport_n = evaluate(obj)
    node_groups.set_modifier_input(mod, "Display Ratio", 1.0)
    full_s, full_n = evaluate(obj)
    out = {"splats": n, "import_seconds": seconds, "peak_rss_mib_before_import": rss_before,
           "peak_rss_mib_after_import": rss_import, "viewport_eval_seconds": viewport_s, "viewport_splats": viewport_n,
           "all_splats_eval_seconds": full_s, "all_splats_shown": full_n, "peak_rss_mib_end": peak_rss_mib(),
           "blender": bpy.app.version_string}
    print(f"{n:,} splats: import {seconds:.2f} s, peak RSS {rss_import:.0f} MiB (before import {rss_before:.0f}); "
          f"viewport geometry nodes {viewport_s:.2f} s for the {viewport_n:,} most visible; "
          f"all {full_n:,} in {full_s:.2f} s; peak RSS at the end {out['peak_rss_mib_end']:.0f} MiB")
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
