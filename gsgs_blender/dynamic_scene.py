"""The 4D validation scene: animated, textured objects seen by a fixed ring of cameras, rendered with
Cycles on the CPU into a NeRF-synthetic JSON with a per-frame "time" (gsgs_engine.io.dynamic).

bpy only. A checker cube travels round a half circle while it spins, a noise sphere bounces, on a
static brick disc; camera 0 of the ring is the held-out camera of the 4D protocol. Small on
purpose (64 px, 10 frames, 10 cameras, 4 samples) so the whole clip renders in a few minutes on
2 cores. Run headless: python -m gsgs_blender.dynamic_scene OUT_DIR [--size 64 --frames 10 ...].
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

import bpy
import bmesh  # noqa: E402,I001  (importable only once bpy is)

from .dataset_render import (camera_intrinsics, camera_to_world, look_at,
                             openimagedenoise_available)
from .demo_scene import _material, _mesh_object

RING_RADIUS = 4.2
RING_HEIGHT = 1.9
TARGET = (0.0, 0.0, 0.35)
GENERATOR = "gsgs_blender.dynamic_scene"


def build_dynamic_scene(cameras: int = 10, frames: int = 10, clear: bool = True) -> tuple[bpy.types.Scene, list]:
    """Build the animated scene (frames 1..`frames`) and a ring of `cameras` cameras; returns (scene, cameras)."""
    if cameras < 2 or frames < 2:
        raise ValueError(f"the dynamic scene needs at least 2 cameras and 2 frames (got {cameras}, {frames})")
    if clear:
        bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.name = "gsgs_dynamic"
    scene.frame_start, scene.frame_end = 1, frames
    coll = bpy.data.collections.new("gsgs dynamic objects")
    scene.collection.children.link(coll)

    ground = _material("dyn_ground", "brick", (0.55, 0.22, 0.12), (0.85, 0.82, 0.72), scale=3.0, roughness=0.8)
    checker = _material("dyn_checker", "checker", (0.8, 0.08, 0.06), (0.92, 0.92, 0.88), scale=4.0)
    noise = _material("dyn_noise", "noise", (0.05, 0.15, 0.7), (0.95, 0.8, 0.1), scale=6.0, roughness=0.35)
    _mesh_object("ground", lambda bm: bmesh.ops.create_circle(bm, cap_ends=True, segments=48, radius=1.4),
                 coll, ground)
    cube = _mesh_object("cube", lambda bm: bmesh.ops.create_cube(bm, size=0.55), coll, checker)
    sphere = _mesh_object("sphere", lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=32, v_segments=16,
                                                                         radius=0.32),
                          coll, noise, smooth=True)

    # One key per frame (linear), so every rendered frame is exactly the pose written here.
    for f in range(1, frames + 1):
        s = (f - 1) / (frames - 1)
        angle = math.pi * s  # the cube sweeps half a circle and turns a quarter turn
        cube.location = (0.7 * math.cos(angle), 0.7 * math.sin(angle) - 0.2, 0.3)
        cube.rotation_euler = (0.0, 0.0, 0.5 * math.pi * s)
        sphere.location = (-0.45, -0.35 + 0.5 * s, 0.32 + 0.6 * math.sin(math.pi * s))
        for obj, path in ((cube, "location"), (cube, "rotation_euler"), (sphere, "location")):
            obj.keyframe_insert(data_path=path, frame=f)
    for obj in (cube, sphere):
        _linear_keys(obj)

    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy = 3.0
    sun.angle = math.radians(8.0)
    sun_obj = bpy.data.objects.new("sun", sun)
    sun_obj.rotation_euler = (math.radians(40), math.radians(10), math.radians(35))
    coll.objects.link(sun_obj)
    world = bpy.data.worlds.new("gsgs_dynamic_world")
    if world.node_tree is None:
        world.use_nodes = True
    bg = world.node_tree.nodes.get("Background") or world.node_tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = (0.55, 0.6, 0.7, 1.0)
    bg.inputs["Strength"].default_value = 0.6
    scene.world = world
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"

    cams = []
    cam_coll = bpy.data.collections.new("gsgs dynamic cameras")
    scene.collection.children.link(cam_coll)
    for i in range(cameras):
        a = 2.0 * math.pi * i / cameras
        data = bpy.data.cameras.new(f"cam{i:02d}")
        data.lens, data.sensor_width, data.sensor_fit = 40.0, 36.0, "AUTO"
        obj = bpy.data.objects.new(f"cam{i:02d}", data)
        obj.matrix_world = look_at((RING_RADIUS * math.cos(a), RING_RADIUS * math.sin(a), RING_HEIGHT), TARGET)
        cam_coll.objects.link(obj)
        cams.append(obj)
    scene.camera = cams[0]
    bpy.context.view_layer.update()
    return scene, cams


def _linear_keys(obj) -> None:
    anim = obj.animation_data
    if anim is None or anim.action is None:
        return
    # Blender 5 keeps F-curves in layered actions (channelbags); older versions on action.fcurves.
    curves = list(getattr(anim.action, "fcurves", []) or [])
    for layer in getattr(anim.action, "layers", []):
        for strip in layer.strips:
            for bag in getattr(strip, "channelbags", []):
                curves.extend(bag.fcurves)
    for fc in curves:
        for kp in fc.keyframe_points:
            kp.interpolation = "LINEAR"


def render_dynamic_dataset(out_dir, cameras: int = 10, frames: int = 10, size: int = 64, samples: int = 4,
                           threads: int = 0, progress=print) -> dict:
    """Build the scene and render every camera at every frame; write transforms.json with "time".

    Each frame entry carries file_path, transform_matrix, intrinsics, camera_name, camera_id and
    time = (frame - 1) / (frames - 1). The JSON is written last (atomically), so it marks a
    complete dataset.
    """
    out = Path(out_dir)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    json_path = out / "transforms.json"
    if json_path.exists():
        json_path.unlink()
    scene, cams = build_dynamic_scene(cameras, frames)
    r = scene.render
    r.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = int(samples)
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = openimagedenoise_available()
    r.resolution_x = r.resolution_y = int(size)
    r.resolution_percentage = 100
    if threads:
        r.threads_mode, r.threads = "FIXED", int(threads)
    r.film_transparent = True
    r.use_persistent_data = True
    r.image_settings.file_format = "PNG"
    r.image_settings.color_mode = "RGBA"
    r.image_settings.color_depth = "8"
    entries = []
    t_all = time.perf_counter()
    for f in range(1, frames + 1):
        scene.frame_set(f)
        t_norm = (f - 1) / (frames - 1)
        for ci, cam in enumerate(cams):
            scene.camera = cam
            stem = f"cam{ci:02d}_f{f - 1:03d}"
            r.filepath = str(out / "frames" / stem)
            bpy.ops.render.render(write_still=True, scene=scene.name)
            png = out / "frames" / f"{stem}.png"
            if not png.is_file():
                raise RuntimeError(f"{png}: Blender did not write the render; check the output folder is writable")
            entry = {"file_path": f"./frames/{stem}", "transform_matrix": camera_to_world(cam),
                     "camera_name": cam.name, "camera_id": ci, "time": t_norm, "frame": f - 1}
            entry.update(camera_intrinsics(cam, scene))
            entries.append(entry)
        if progress:
            progress(f"[gsgs dynamic] frame {f}/{frames} ({len(cams)} cameras) {time.perf_counter() - t_all:.1f}s")
    data = dict(camera_intrinsics(cams[0], scene))
    data.update({"frames": entries, "generator": GENERATOR, "blender_version": bpy.app.version_string,
                 "samples": int(samples), "cameras": len(cams), "num_frames": frames,
                 "test_camera": 0, "time": "normalised (frame - 1) / (frames - 1)"})
    tmp = json_path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, json_path)
    return {"out_dir": str(out), "views": len(entries), "seconds": time.perf_counter() - t_all,
            "cameras": len(cams), "frames": frames, "size": size, "samples": samples}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description="Render the gsgs 4D validation scene (NeRF-synthetic JSON with time)")
    p.add_argument("out")
    p.add_argument("--cameras", type=int, default=10)
    p.add_argument("--frames", type=int, default=10)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--samples", type=int, default=4)
    p.add_argument("--threads", type=int, default=0)
    args = p.parse_args(argv)
    summary = render_dynamic_dataset(args.out, args.cameras, args.frames, args.size, args.samples, args.threads)
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
