"""Render a NeRF-synthetic validation dataset from a .blend: a hemisphere (or sphere) rig of train and
test views around the scene's objects, or the cameras of two collections you name.

Inside Blender:
    blender --background scene.blend --python scripts/render_validation.py -- --out DIR \
        [--views 100 --test-views 25 --resolution 200 --depth]
With the bpy module:
    python scripts/render_validation.py --blend scene.blend --out DIR [same options]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))  # Blender's Python does not know the project


def parse_args(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="render_validation.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--out", required=True, help="output folder for transforms_*.json and images")
    p.add_argument("--blend", default=None, help=".blend to open (needed with the bpy module; optional in Blender)")
    p.add_argument("--views", type=int, default=100, help="training views on the rig (default 100)")
    p.add_argument("--test-views", type=int, default=25, help="test views on the rig (default 25)")
    p.add_argument("--resolution", type=int, default=200, help="square image size in pixels (default 200)")
    p.add_argument("--depth", action="store_true", help="also write the depth pass (<split>/r_<i>_depth.exr)")
    p.add_argument("--samples", type=int, default=16, help="Cycles samples per pixel (default 16)")
    p.add_argument("--no-denoise", action="store_true", help="skip OpenImageDenoise")
    p.add_argument("--seed", type=int, default=0, help="rig seed (test views use seed + 1)")
    p.add_argument("--distribution", choices=["fibonacci", "random"], default="fibonacci")
    p.add_argument("--full-sphere", action="store_true", help="sample the whole sphere instead of the upper hemisphere")
    p.add_argument("--min-elevation", type=float, default=10.0, help="hemisphere: lowest elevation in degrees")
    p.add_argument("--max-elevation", type=float, default=80.0, help="hemisphere: highest elevation in degrees")
    p.add_argument("--radius", type=float, default=None, help="rig radius (default: frames the scene's objects)")
    p.add_argument("--target", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                   help="look-at point (default: centre of the objects' bounding box)")
    p.add_argument("--lens", type=float, default=50.0, help="rig focal length in mm on a 36 mm sensor (default 50)")
    p.add_argument("--train-collection", default=None, help="use this collection's cameras as the train views")
    p.add_argument("--test-collection", default=None, help="use this collection's cameras as the test views")
    p.add_argument("--threads", type=int, default=0, help="Cycles CPU threads (0 = all cores)")
    return p.parse_args(argv)


def script_argv(argv: list[str]) -> list[str]:
    """Blender passes its own arguments too: the script's follow `--`; the bpy module gets them directly."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


def collection_cameras(name: str):
    import bpy

    from gsgs_engine import GsgsError

    coll = bpy.data.collections.get(name)
    if coll is None:
        raise GsgsError(f"{bpy.data.filepath or 'this file'}: no collection named {name!r}; available: "
                        f"{', '.join(c.name for c in bpy.data.collections) or 'none'}")
    cams = sorted((o for o in coll.all_objects if o.type == "CAMERA"), key=lambda o: o.name)
    if not cams:
        raise GsgsError(f"collection {name!r} holds no camera objects; add cameras or drop --{name} option")
    return cams


def build_splits(args: argparse.Namespace, scene) -> tuple[dict, object, str]:
    """{"train": cams, "test": cams}, the temporary rig collection (or None) and a description."""
    import bpy

    from gsgs_blender import dataset_render as dr

    if args.train_collection or args.test_collection:
        splits = {}
        if args.train_collection:
            splits["train"] = collection_cameras(args.train_collection)
        if args.test_collection:
            splits["test"] = collection_cameras(args.test_collection)
        return splits, None, "cameras from " + ", ".join(f"{k}={len(v)}" for k, v in splits.items())
    centre, bound = dr.scene_bounds(scene)
    target = tuple(args.target) if args.target else tuple(centre)
    radius = args.radius or dr.framing_radius(bound, lens_mm=args.lens)
    common = dict(radius=radius, target=target, hemisphere=not args.full_sphere, distribution=args.distribution,
                  min_elevation_deg=args.min_elevation, max_elevation_deg=args.max_elevation, lens_mm=args.lens)
    rig_coll = bpy.data.collections.new("gsgs validation rig")
    scene.collection.children.link(rig_coll)
    splits = {}
    if args.views > 0:
        splits["train"] = dr.add_rig_cameras(dr.SphereRig(count=args.views, seed=args.seed, **common), "rig_train",
                                             scene, rig_coll)
    if args.test_views > 0:
        splits["test"] = dr.add_rig_cameras(dr.SphereRig(count=args.test_views, seed=args.seed + 1, **common), "rig_test",
                                            scene, rig_coll)
    shape = "sphere" if args.full_sphere else "hemisphere"
    desc = (f"{shape} rig r={radius:.3f} around ({target[0]:.2f}, {target[1]:.2f}, {target[2]:.2f}): "
            f"{args.views} train + {args.test_views} test views")
    return splits, rig_coll, desc


def main(argv: list[str] | None = None) -> int:
    args = parse_args(script_argv(sys.argv if argv is None else argv))
    import bpy

    from gsgs_blender import dataset_render as dr
    from gsgs_engine import GsgsError

    try:
        if args.blend:
            blend = Path(args.blend)
            if not blend.is_file():
                raise GsgsError(f"{blend}: no such .blend file; pass the scene to render with --blend")
            bpy.ops.wm.open_mainfile(filepath=str(blend.resolve()))
        elif not bpy.app.binary_path:  # the bpy module starts from Blender's default cube, never what you meant
            raise GsgsError("no scene to render: with the bpy module pass --blend scene.blend "
                            "(inside Blender the open file is used)")
        scene = bpy.context.scene
        splits, rig_coll, desc = build_splits(args, scene)
        print(f"[render_validation] {bpy.data.filepath or 'unsaved scene'}: {desc}, "
              f"{args.resolution}x{args.resolution}, {args.samples} samples{', depth' if args.depth else ''}",
              flush=True)
        try:
            summary = dr.render_dataset(args.out, splits, scene=scene, resolution=args.resolution,
                                        samples=args.samples, denoise=not args.no_denoise, with_depth=args.depth,
                                        threads=args.threads, progress=lambda m: print(m, flush=True))
        finally:
            if rig_coll is not None:  # leave the user's file as it was
                for obj in list(rig_coll.objects):
                    data = obj.data
                    bpy.data.objects.remove(obj)
                    bpy.data.cameras.remove(data)
                bpy.data.collections.remove(rig_coll)
    except GsgsError as exc:
        print(f"render_validation: error: {exc}", file=sys.stderr, flush=True)
        return 2
    views = sum(s["views"] for s in summary["splits"].values())
    print(f"[render_validation] wrote {views} views to {args.out} in {summary['seconds']:.0f} s", flush=True)
    return 0


if __name__ == "__main__":
    code = main()
    if code:
        sys.exit(code)
