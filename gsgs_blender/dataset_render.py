"""Render a NeRF-synthetic dataset (transforms_*.json, RGBA PNG, optional depth EXR) from a Blender scene.

bpy only (no torch). The cameras are explicit camera objects or a seeded sampler on a
sphere / hemisphere; Cycles renders on the CPU with film_transparent, so the output loads
like the original NeRF-synthetic scenes (`gsgs_engine.io.load_scene(path, format="blender")`).
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence

import bpy
from mathutils import Matrix, Vector

from gsgs_engine import GsgsError

DEPTH_SUFFIX = "_depth"  # depth EXR of frame "r_3" is "r_3_depth.exr": one float channel "V", planar z


# ---------------------------------------------------------------------------------------------
# Camera rig: seeded positions on a sphere or hemisphere, cameras looking at a target
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SphereRig:
    """`count` cameras at `radius` around `target`, looking at it (world +Z is up).

    distribution "fibonacci" spreads the views evenly (the seed turns the spiral about Z),
    "random" draws them uniformly on the (hemi)sphere; both are deterministic for a seed.
    On a hemisphere the elevations stay within [min_elevation_deg, max_elevation_deg].
    """

    count: int
    radius: float
    target: tuple[float, float, float] = (0.0, 0.0, 0.0)
    seed: int = 0
    hemisphere: bool = True
    min_elevation_deg: float = 10.0
    max_elevation_deg: float = 80.0
    distribution: str = "fibonacci"
    lens_mm: float = 50.0
    sensor_width_mm: float = 36.0

    def validate(self) -> "SphereRig":
        if self.count < 1:
            raise GsgsError(f"camera rig: count must be >= 1 (got {self.count})")
        if not (self.radius > 0 and math.isfinite(self.radius)):
            raise GsgsError(f"camera rig: radius must be positive (got {self.radius})")
        if self.distribution not in ("fibonacci", "random"):
            raise GsgsError(f"camera rig: distribution must be 'fibonacci' or 'random' (got {self.distribution!r})")
        lo, hi = self._z_range()
        if not lo < hi:
            raise GsgsError(f"camera rig: min_elevation_deg ({self.min_elevation_deg}) must be below "
                            f"max_elevation_deg ({self.max_elevation_deg})")
        return self

    def _z_range(self) -> tuple[float, float]:
        if not self.hemisphere:
            return -1.0, 1.0
        return math.sin(math.radians(self.min_elevation_deg)), math.sin(math.radians(self.max_elevation_deg))

    def positions(self) -> list[Vector]:
        """World-space camera centres (uniform in area: z = sin(elevation) is sampled uniformly)."""
        import random

        self.validate()
        rng = random.Random(self.seed)
        lo, hi = self._z_range()
        golden = math.pi * (3.0 - math.sqrt(5.0))
        phase = rng.uniform(0.0, 2.0 * math.pi)
        out = []
        for i in range(self.count):
            if self.distribution == "fibonacci":
                z = hi - (hi - lo) * (i + 0.5) / self.count
                phi = phase + golden * i
            else:
                z = rng.uniform(lo, hi)
                phi = rng.uniform(0.0, 2.0 * math.pi)
            r_xy = math.sqrt(max(0.0, 1.0 - z * z))
            d = Vector((r_xy * math.cos(phi), r_xy * math.sin(phi), z))
            out.append(Vector(self.target) + self.radius * d)
        return out


def look_at(location: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0)) -> Matrix:
    """4x4 world matrix of a Blender camera at `location` looking at `target` (camera -Z forward, +Y up)."""
    loc, tgt, up_v = Vector(location), Vector(target), Vector(up)
    forward = tgt - loc
    if forward.length < 1e-12:
        raise GsgsError("camera rig: a camera sits on its look-at target; move the target or increase the radius")
    forward.normalize()
    right = forward.cross(up_v)
    if right.length < 1e-6:  # looking straight up/down: any horizontal right vector will do
        right = forward.cross(Vector((0.0, 1.0, 0.0)))
    right.normalize()
    cam_up = right.cross(forward)
    rot = Matrix((right, cam_up, -forward)).transposed()  # columns: camera x, y, z axes in world
    m = rot.to_4x4()
    m.translation = loc
    return m


def add_rig_cameras(rig: SphereRig, name_prefix: str, scene: bpy.types.Scene | None = None,
                    collection: bpy.types.Collection | None = None) -> list[bpy.types.Object]:
    """Create one camera object per rig position (named `<prefix>_000` ...), linked into `collection`."""
    scene = scene or bpy.context.scene
    collection = collection or scene.collection
    objs = []
    for i, pos in enumerate(rig.positions()):
        data = bpy.data.cameras.new(f"{name_prefix}_{i:03d}")
        data.lens = rig.lens_mm
        data.sensor_width = rig.sensor_width_mm
        data.sensor_fit = "AUTO"
        obj = bpy.data.objects.new(f"{name_prefix}_{i:03d}", data)
        obj.matrix_world = look_at(pos, rig.target)
        collection.objects.link(obj)
        objs.append(obj)
    return objs


def scene_bounds(scene: bpy.types.Scene | None = None) -> tuple[Vector, float]:
    """Centre and radius of the bounding sphere of the scene's renderable mesh-like objects."""
    scene = scene or bpy.context.scene
    depsgraph = bpy.context.evaluated_depsgraph_get()
    lo = Vector((math.inf,) * 3)
    hi = Vector((-math.inf,) * 3)
    found = False
    for obj in scene.objects:
        if obj.type not in {"MESH", "CURVE", "SURFACE", "META", "FONT", "POINTCLOUD", "VOLUME", "CURVES"}:
            continue
        if obj.hide_render:
            continue
        ev = obj.evaluated_get(depsgraph)
        for corner in ev.bound_box:
            w = ev.matrix_world @ Vector(corner)
            lo = Vector(map(min, lo, w))
            hi = Vector(map(max, hi, w))
            found = True
    if not found:
        raise GsgsError(f"scene {scene.name!r}: no renderable objects to frame; add geometry or give explicit cameras")
    centre = (lo + hi) / 2.0
    return centre, max((hi - lo).length / 2.0, 1e-6)


def framing_radius(bound_radius: float, lens_mm: float = 50.0, sensor_mm: float = 36.0, margin: float = 1.15) -> float:
    """Camera distance at which a sphere of `bound_radius` fits in a square frame of that lens."""
    half_fov = math.atan(sensor_mm / (2.0 * lens_mm))
    return margin * bound_radius / math.sin(half_fov)


# ---------------------------------------------------------------------------------------------
# Camera export: exactly what the renders use
# ---------------------------------------------------------------------------------------------
def render_size(scene: bpy.types.Scene) -> tuple[int, int]:
    pct = scene.render.resolution_percentage / 100.0
    return int(scene.render.resolution_x * pct), int(scene.render.resolution_y * pct)


def camera_intrinsics(cam_obj: bpy.types.Object, scene: bpy.types.Scene) -> dict:
    """Pinhole intrinsics of a Blender camera for the scene's render size.

    Pixel coordinates put the top-left pixel centre at (0.5, 0.5), so an unshifted camera has
    cx = w / 2. Follows Blender's view plane (sensor fit, shift, pixel aspect) exactly.
    """
    cam = cam_obj.data
    if cam_obj.type != "CAMERA":
        raise GsgsError(f"object {cam_obj.name!r} is a {cam_obj.type}, not a camera; pick camera objects for the rig")
    if cam.type != "PERSP":
        raise GsgsError(f"camera {cam_obj.name!r} is {cam.type}; NeRF datasets need perspective cameras "
                        "(set Camera > Lens > Type to Perspective)")
    w, h = render_size(scene)
    asp_x, asp_y = scene.render.pixel_aspect_x, scene.render.pixel_aspect_y
    ycor = asp_y / asp_x
    fit = cam.sensor_fit
    if fit == "AUTO":
        fit = "HORIZONTAL" if asp_x * w >= asp_y * h else "VERTICAL"
        sensor = cam.sensor_width  # AUTO always measures the larger side with sensor_width
    else:
        sensor = cam.sensor_width if fit == "HORIZONTAL" else cam.sensor_height
    view_fac = w if fit == "HORIZONTAL" else ycor * h  # view-plane extent (in x pixels) the sensor spans
    fx = cam.lens / sensor * view_fac
    fy = fx / ycor
    cx = w / 2.0 - cam.shift_x * view_fac
    cy = h / 2.0 + cam.shift_y * view_fac / ycor
    return {
        "camera_angle_x": 2.0 * math.atan(w / (2.0 * fx)),
        "camera_angle_y": 2.0 * math.atan(h / (2.0 * fy)),
        "fl_x": fx, "fl_y": fy, "cx": cx, "cy": cy, "w": w, "h": h,
    }


def camera_to_world(cam_obj: bpy.types.Object) -> list[list[float]]:
    """OpenGL camera-to-world 4x4 (matrix_world without object scale, which renders ignore)."""
    loc, rot, _scale = cam_obj.matrix_world.decompose()
    m = rot.to_matrix().to_4x4()
    m.translation = loc
    return [list(map(float, row)) for row in m]


# ---------------------------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------------------------
def openimagedenoise_available() -> bool:
    """Whether this Blender build ships OpenImageDenoise (the pip bpy module may not)."""
    try:
        import _cycles
    except ImportError:
        return False
    return bool(getattr(_cycles, "with_openimagedenoise", False))


class _SavedSettings:
    """Set attributes for the duration of a render and put the user's values back afterwards."""

    def __init__(self):
        self._saved: list[tuple[object, str, object]] = []

    def set(self, owner, attr: str, value) -> None:
        self._saved.append((owner, attr, getattr(owner, attr)))
        setattr(owner, attr, value)

    def restore(self) -> None:
        for owner, attr, value in reversed(self._saved):
            try:
                setattr(owner, attr, value)
            except (AttributeError, TypeError, ReferenceError):
                pass  # the owner was removed (e.g. our temporary compositor); nothing to restore
        self._saved.clear()


def _render_view_layer(scene: bpy.types.Scene) -> bpy.types.ViewLayer:
    for layer in scene.view_layers:
        if layer.use:
            return layer
    raise GsgsError(f"scene {scene.name!r}: every view layer is disabled for rendering; enable one")


def _depth_compositor(scene: bpy.types.Scene, layer: bpy.types.ViewLayer):
    """A compositor that writes the Depth pass as a single-channel float32 EXR.

    Returns (node tree, the nodes added, set_output(directory, stem)). Blender 5 gives the scene
    a compositor node group; Blender 4.x keeps scene.node_tree and needs a Composite node, or the
    render result would be empty.
    """
    legacy = not hasattr(scene, "compositing_node_group")
    if legacy:
        scene.use_nodes = True
        tree = scene.node_tree
    else:
        tree = bpy.data.node_groups.new("gsgs_depth_output", "CompositorNodeTree")
    rl = tree.nodes.new("CompositorNodeRLayers")
    rl.scene = scene
    rl.layer = layer.name
    out = tree.nodes.new("CompositorNodeOutputFile")
    if hasattr(out.format, "media_type"):
        out.format.media_type = "IMAGE"
    out.format.file_format = "OPEN_EXR"
    out.format.color_depth = "32"
    out.format.color_mode = "BW"
    out.format.exr_codec = "ZIP"
    added = [rl, out]
    if legacy:
        composite = tree.nodes.new("CompositorNodeComposite")
        added.append(composite)
        tree.links.new(rl.outputs["Image"], composite.inputs["Image"])
        tree.links.new(rl.outputs["Depth"], out.inputs[0])

        def set_output(directory: Path, stem: str) -> None:
            out.base_path = str(directory)
            out.file_slots[0].path = stem + DEPTH_SUFFIX + "_"  # Blender 4 appends the frame number

    else:
        out.file_output_items.new("FLOAT", "depth")
        tree.links.new(rl.outputs["Depth"], out.inputs["depth"])

        def set_output(directory: Path, stem: str) -> None:
            out.directory = str(directory)
            out.file_name = stem + "_"  # + the item name "depth" -> r_<i>_depth.exr

    return tree, added, set_output


def _collect_depth(split_dir: Path, stem: str) -> Path:
    """The depth EXR of one view under its final name (older Blenders add a frame number)."""
    final = split_dir / f"{stem}{DEPTH_SUFFIX}.exr"
    if final.is_file():
        return final
    numbered = sorted(split_dir.glob(f"{stem}{DEPTH_SUFFIX}_[0-9]*.exr"), key=lambda p: p.stat().st_mtime)
    if not numbered:
        raise GsgsError(f"{final}: the depth pass was not written; check that the output folder is writable")
    os.replace(numbered[-1], final)
    return final


def _write_json(path: Path, data: dict) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(data, indent=2))
    os.replace(tmp, path)  # the JSON appears only when complete: it marks a finished split


def render_dataset(out_dir: str | os.PathLike, splits: dict[str, Iterable[bpy.types.Object]],
                   scene: bpy.types.Scene | None = None, resolution: int | tuple[int, int] | None = None,
                   samples: int = 16, denoise: bool = True, with_depth: bool = False, threads: int = 0,
                   progress: Callable[[str], None] | None = print) -> dict:
    """Render every camera of every split; write `transforms_<split>.json` and `<split>/r_<i>.png`.

    splits: {"train": [camera objects], "test": [...], ...}. resolution: an int for a square
    image, (w, h), or None to keep the scene's. The depth pass (`<split>/r_<i>_depth.exr`, planar
    camera-z distance, 1e10 where nothing was hit) is rendered only when `with_depth` is set.
    The scene's render settings are restored afterwards. Returns a summary dict.
    """
    scene = scene or bpy.context.scene
    out = Path(out_dir)
    splits = {name: list(cams) for name, cams in splits.items()}
    splits = {name: cams for name, cams in splits.items() if cams}  # an empty split gets no JSON
    if not splits:
        raise GsgsError(f"{out}: no cameras to render; give at least one camera in a split")
    for name, cams in splits.items():
        if not name or "/" in name or "\\" in name:
            raise GsgsError(f"{out}: split name {name!r} is not a plain folder name")
        for cam in cams:
            camera_intrinsics(cam, scene)  # fail before rendering anything if a camera is unusable
    out.mkdir(parents=True, exist_ok=True)

    saved = _SavedSettings()
    depth_tree = depth_nodes = None
    summary = {"out_dir": str(out), "splits": {}, "denoiser": None, "with_depth": with_depth}
    try:
        r = scene.render
        saved.set(r, "engine", "CYCLES")
        saved.set(scene.cycles, "device", "CPU")
        saved.set(scene.cycles, "samples", int(samples))
        saved.set(scene.cycles, "use_adaptive_sampling", False)  # same noise level in every view
        use_oidn = denoise and openimagedenoise_available()
        saved.set(scene.cycles, "use_denoising", use_oidn)
        if use_oidn:
            saved.set(scene.cycles, "denoiser", "OPENIMAGEDENOISE")
            summary["denoiser"] = "OPENIMAGEDENOISE"
        if resolution is not None:
            w, h = (resolution, resolution) if isinstance(resolution, int) else resolution
            saved.set(r, "resolution_x", int(w))
            saved.set(r, "resolution_y", int(h))
            saved.set(r, "resolution_percentage", 100)
        if threads:
            saved.set(r, "threads_mode", "FIXED")
            saved.set(r, "threads", int(threads))
        saved.set(r, "film_transparent", True)
        saved.set(r, "use_persistent_data", True)  # only the camera changes between views: keep the BVH
        saved.set(r, "use_file_extension", True)
        if hasattr(r.image_settings, "media_type"):  # Blender 5 groups formats by media type
            saved.set(r.image_settings, "media_type", "IMAGE")
        saved.set(r.image_settings, "file_format", "PNG")
        saved.set(r.image_settings, "color_mode", "RGBA")
        saved.set(r.image_settings, "color_depth", "8")
        saved.set(r, "filepath", r.filepath)
        saved.set(scene, "camera", scene.camera)
        layer = _render_view_layer(scene)
        saved.set(r, "use_compositing", with_depth)
        if with_depth:
            saved.set(layer, "use_pass_z", True)
            if hasattr(scene, "compositing_node_group"):
                saved.set(scene, "compositing_node_group", None)  # restored after the tree is made
                depth_tree, depth_nodes, set_depth_output = _depth_compositor(scene, layer)
                scene.compositing_node_group = depth_tree
            else:
                saved.set(scene, "use_nodes", scene.use_nodes)
                depth_tree, depth_nodes, set_depth_output = _depth_compositor(scene, layer)
        if progress and denoise and not use_oidn:
            progress("[gsgs render] OpenImageDenoise is not in this Blender build; rendering without denoising")

        w, h = render_size(scene)
        total = sum(len(c) for c in splits.values())
        done = 0
        t_all = time.perf_counter()
        for split, cams in splits.items():
            split_dir = out / split
            split_dir.mkdir(parents=True, exist_ok=True)
            json_path = out / f"transforms_{split}.json"
            if json_path.exists():
                json_path.unlink()  # re-rendering: the old JSON must not vouch for new, partial images
            frames = []
            t_split = time.perf_counter()
            for i, cam in enumerate(cams):
                stem = f"r_{i}"
                scene.camera = cam
                r.filepath = str(split_dir / stem)
                if with_depth:
                    set_depth_output(split_dir, stem)
                t0 = time.perf_counter()
                bpy.ops.render.render(write_still=True, scene=scene.name)
                png = split_dir / f"{stem}.png"
                if not png.is_file():
                    raise GsgsError(f"{png}: Blender did not write the render; check the output folder is writable")
                frame = {"file_path": f"./{split}/{stem}", "transform_matrix": camera_to_world(cam),
                         "camera_name": cam.name}
                intr = camera_intrinsics(cam, scene)
                frame.update(intr)  # per-frame intrinsics: rigs may mix lenses
                if with_depth:
                    depth = _collect_depth(split_dir, stem)
                    frame["depth_file_path"] = f"./{split}/{depth.name}"
                frames.append(frame)
                done += 1
                if progress:
                    progress(f"[gsgs render] {split} {i + 1}/{len(cams)} ({done}/{total}) {cam.name} -> "
                             f"{png.name} {time.perf_counter() - t0:.1f}s")
            data = camera_intrinsics(cams[0], scene)
            data.update({"frames": frames, "generator": "gsgs_blender.dataset_render",
                         "blender_version": bpy.app.version_string, "samples": int(samples),
                         "denoiser": summary["denoiser"], "depth": "planar camera z, EXR channel V" if with_depth else None})
            _write_json(json_path, data)
            summary["splits"][split] = {"views": len(cams), "seconds": time.perf_counter() - t_split,
                                        "json": str(json_path)}
        summary["seconds"] = time.perf_counter() - t_all
        summary["width"], summary["height"] = w, h
    finally:
        saved.restore()
        if depth_tree is not None:
            if hasattr(scene, "compositing_node_group"):
                bpy.data.node_groups.remove(depth_tree)
            else:  # Blender 4: the tree is the user's scene.node_tree; remove only our nodes
                for node in depth_nodes:
                    depth_tree.nodes.remove(node)
    return summary


def dataset_is_complete(path: str | os.PathLike, splits: Sequence[str] = ("train", "test"),
                        counts: dict[str, int] | None = None) -> bool:
    """True when every split's JSON exists and every image it lists is on disk (counts: expected views)."""
    root = Path(path)
    for split in splits:
        jp = root / f"transforms_{split}.json"
        try:
            frames = json.loads(jp.read_text())["frames"]
        except (OSError, ValueError, KeyError):
            return False
        if counts and len(frames) != counts.get(split, len(frames)):
            return False
        for f in frames:
            p = root / f["file_path"]
            if not (p.is_file() or p.with_suffix(".png").is_file()):
                return False
    return True
