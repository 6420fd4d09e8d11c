"""Photos -> cameras -> pseudo path -> trained splats -> a saved .blend, without the UI.

    blender --background --python scripts/reconstruct.py -- --photos DIR --out DIR [options]
    python scripts/reconstruct.py --photos DIR --out DIR [options]      (the bpy module)

The same add-on operators the sidebar uses run here; each engine job runs in its own child
process and this script waits for it, printing progress. OUT receives jobs/ (the SfM and
training job folders) and scene.blend (cameras with their photos, sparse points, pseudo path,
imported splats).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def parse_args(argv: list[str]) -> argparse.Namespace:
    if "--" in argv:  # Blender passes its own arguments first
        argv = argv[argv.index("--") + 1:]
    elif argv and Path(argv[0]).name.startswith("blender"):
        argv = []
    p = argparse.ArgumentParser(prog="reconstruct.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--photos", required=True, help="folder of photos (no poses needed)")
    p.add_argument("--out", required=True, help="output folder: jobs/ and scene.blend")
    p.add_argument("--python", default=None, help="engine Python with torch (default: the repo's .venv)")
    p.add_argument("--preset", default="balanced", choices=["fast", "balanced", "best"],
                   help="training settings from the measured accuracy/time front, as the Train panel "
                        "(default balanced: 1000 iterations, the engine's default); flags below override it")
    p.add_argument("--iters", type=int, default=None, help="training iterations (default: the preset's)")
    p.add_argument("--resolution-scale", type=float, default=None,
                   help="train on images scaled by this (default: the preset's)")
    p.add_argument("--max-side", type=int, default=None,
                   help="train on views at most this many px on their longer side (default: the preset's; 0: no cap)")
    p.add_argument("--max-image-size", type=int, default=1600, help="SfM works on photos of this longer side")
    p.add_argument("--prior", default=None, choices=["auto", "diffusion", "warp", "depth", "none"],
                   help="generative prior (default: the preset's, none = plain 3DGS; auto: diffusion when model "
                        "folders are given, else warp-inpaint). The path's pseudo poses are used only with a prior")
    p.add_argument("--diffusion-model", default="", help="local Stable Diffusion 1.5-class folder (diffusers)")
    p.add_argument("--depth-adapter", default="", help="local depth T2I-Adapter folder (diffusers)")
    p.add_argument("--pseudo-views", type=int, default=16, help="pseudo poses along a path through the cameras "
                                                                "(0: none)")
    p.add_argument("--timeout", type=float, default=0.0,
                   help="give up on a job (camera solve, training) after this many seconds, cancelling it "
                        "(default 0: wait until it ends)")
    return p.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(list(sys.argv[1:] if argv is None else argv))
    sys.path.insert(0, str(REPO))
    import bpy

    import gsgs_blender
    from gsgs_blender import ops_train, preferences, pseudo_paths, train_estimate
    from gsgs_engine.job import Job

    out = Path(args.out).resolve()
    photos = Path(args.photos).resolve()
    if not photos.is_dir():
        print(f"reconstruct: error: {photos}: not a folder of photos", file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    gsgs_blender.register()
    # Registered directly (not through the add-on system): settings go to the fallback preferences.
    prefs = preferences._FALLBACK
    prefs.python_path = args.python or preferences.default_python()
    prefs.engine_root = preferences.default_engine_root()
    prefs.jobs_dir = str(out / "jobs")
    prefs.diffusion_dir = args.diffusion_model
    prefs.depth_adapter_dir = args.depth_adapter
    scene = bpy.context.scene
    s = scene.gsgs
    t0 = time.monotonic()
    try:
        s.photos_dir = str(photos)
        s.max_image_size = args.max_image_size
        print(f"reconstruct: solving cameras for {photos}", flush=True)
        bpy.ops.gsgs.import_photos(timeout=args.timeout)
        cams = [o for o in s.camera_collection.all_objects if o.type == "CAMERA"] if s.camera_collection else []
        print(f"reconstruct: {len(cams)} cameras ({time.monotonic() - t0:.0f} s)", flush=True)
        if args.pseudo_views > 0 and len(cams) >= 2:
            bpy.ops.gsgs.make_pseudo_path(closed=len(cams) >= 3)
            s.pseudo_count = args.pseudo_views
            bpy.ops.gsgs.sample_pseudo_poses()
            print(f"reconstruct: {args.pseudo_views} pseudo poses on the path", flush=True)
        s.preset = args.preset
        if args.iters is not None:
            s.iterations = args.iters
        if args.resolution_scale is not None:
            s.resolution_scale = args.resolution_scale
        if args.max_side is not None:
            s.max_side = args.max_side
        if args.prior is not None:
            s.generator = args.prior
        if s.generator == "none" and len(pseudo_paths.poses_from_json(s.pseudo_poses)):
            print("reconstruct: note: the path's pseudo poses are used only with a prior (--prior auto)", flush=True)
        ops_train.probe_machine(bpy.context)  # the estimate follows this machine's measured speed
        print(f"reconstruct: training {s.iterations} iterations (preset {s.preset}); estimated "
              f"{train_estimate.estimate_text(scene, device=train_estimate.device_of(preferences.get_prefs()))}",
              flush=True)
        bpy.ops.gsgs.train(timeout=args.timeout)
    except RuntimeError as exc:  # an operator reported an error
        print(f"reconstruct: error: {str(exc).strip()}", file=sys.stderr)
        _save(bpy, out)
        return 2
    finally:
        elapsed = time.monotonic() - t0
    status = Job.open(bpy.path.abspath(s.train_job)).status() or {}
    blend = _save(bpy, out)
    obj = s.result_object
    count = obj["gsgs_count"] if obj is not None else 0
    print(f"reconstruct: {status.get('state')}: {status.get('message', '')}")
    print(f"reconstruct: {count} splats, {elapsed:.0f} s; saved {blend}")
    gsgs_blender.unregister()
    return 0 if status.get("state") == "ok" and count > 0 else 1


def _save(bpy, out: Path) -> Path:
    blend = out / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    return blend


if __name__ == "__main__":
    sys.exit(main())
