"""The learned wall behind the splats (the engine's background sphere) as a Blender object.

An inward-shell run (a dome of cameras) trains a texture on the sphere through its cameras
(gsgs_engine/train/background_sphere.py) and writes it beside the PLY as background_sphere.png, with its
centre, radius and mapping in metrics.json (`plan.background_sphere`, world units). Here it becomes a sphere
mesh at that centre and radius whose emission colour is the texture looked up by the direction from the
centre, exactly the engine's equirectangular mapping, at the point where the camera ray leaves the shell (its far
intersection, as the engine takes it). The mesh itself lies far behind the shell (MESH_RADIUS), so every splat is
in front of it, as in the engine's compositing; its shader traces the ray back to the shell:

    u = atan2(y, x) / (2 pi) + 1/2,   v = asin(z) / pi + 1/2      (v = 1: the image's top row, +z)

bilinear between texel centres and clamped at the image's edges, as the engine's grid_sample. The sphere is seen
by camera rays only (it lights nothing and casts no shadow), so through the splats' transparency a render shows
it where the engine composites it: under the splats' remaining transmittance. Its image is read as Non-Color in
the EXACT colour mode (Raw view transform: the engine's display values pass through) and as sRGB in LINEAR.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import bpy

OBJECT_NAME = "GS-GS Background Sphere"
SEGMENTS = (64, 32)  # around, pole to pole (the shader finds the true sphere's point, not the mesh's)
# The mesh lies at MESH_RADIUS shell radii: behind every splat, as the engine composites the background after all
# of them (a reconstructed wall's splats lie at and beyond the shell). Its shader traces the camera ray back to
# where it leaves the shell of radius 1 (object space) and looks the texture up there.
MESH_RADIUS = 8.0


def fit_clip_end(cam_obj, sphere_obj) -> list[str]:
    """Extend a camera's clip end to reach the back of the sphere's mesh (a camera imported with the scene's far
    bound would cut it off and show the world instead); the line that changed, if any. The engine's novel views
    have no far plane, so a larger clip end only brings Blender closer to them."""
    if cam_obj is None or getattr(cam_obj, "type", None) != "CAMERA":
        return []
    centre = sphere_obj.matrix_world.translation
    reach = ((cam_obj.matrix_world.translation - centre).length + MESH_RADIUS * max(sphere_obj.scale)) * 1.01
    if cam_obj.data.clip_end >= reach:
        return []
    old = cam_obj.data.clip_end
    cam_obj.data.clip_end = reach
    return [f"{cam_obj.name} clip end: {old:.4g} -> {reach:.4g} (reaches the background sphere)"]


def record_of(result_dir) -> dict | None:
    """metrics.json's `plan.background_sphere` of a result folder, or None (no sphere, no metrics)."""
    path = Path(result_dir) / "metrics.json"
    try:
        plan = json.loads(path.read_text()).get("plan", {})
    except (OSError, ValueError):
        return None
    record = plan.get("background_sphere")
    return record if isinstance(record, dict) else None


def _colourspace(colour_mode: str) -> str:
    return "sRGB" if colour_mode == "LINEAR" else "Non-Color"


def set_colour_mode(obj, colour_mode: str) -> list[str]:
    """Follow the scene's colour mode (the image's colour space; see the module docstring); the line that
    changed, if any."""
    image = obj.get("gsgs_image")
    img = bpy.data.images.get(image) if image else None
    if img is None or img.colorspace_settings.name == _colourspace(colour_mode):
        return []
    old = img.colorspace_settings.name
    img.colorspace_settings.name = _colourspace(colour_mode)
    return [f"{obj.name} texture colour space: {old} -> {img.colorspace_settings.name} (matches the "
            f"{colour_mode.lower()} colour mode)"]


def _material(image) -> bpy.types.Material:
    mat = bpy.data.materials.new(OBJECT_NAME)
    if mat.node_tree is None:  # Blender < 5 creates the tree only on request
        mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()

    def vmath(op, a, b=None, scale=None):
        n = nodes.new("ShaderNodeVectorMath")
        n.operation = op
        links.new(a, n.inputs[0])
        if b is not None:
            links.new(b, n.inputs[1])
        if scale is not None:
            if isinstance(scale, (int, float)):
                n.inputs["Scale"].default_value = float(scale)
            else:
                links.new(scale, n.inputs["Scale"])
        return n.outputs["Value"] if op == "DOT_PRODUCT" else n.outputs["Vector"]

    def math_node(op, a, b=None):
        n = nodes.new("ShaderNodeMath")
        n.operation = op
        for i, v in enumerate((a, b)):
            if v is None:
                continue
            if isinstance(v, (int, float)):
                n.inputs[i].default_value = float(v)
            else:
                links.new(v, n.inputs[i])
        return n.outputs[0]

    # The hit point p on the mesh (object space: the unit is the shell's radius) and the ray's direction d; the
    # point q where the ray leaves the unit sphere is the last one before p: q = p - u d with
    # u = p.d - sqrt(max((p.d)^2 - |p|^2 + 1, 0)) (the engine's far root; a miss takes the closest approach).
    coords = nodes.new("ShaderNodeTexCoord")
    geometry = nodes.new("ShaderNodeNewGeometry")
    p = coords.outputs["Object"]
    d = vmath("SCALE", geometry.outputs["Incoming"], scale=-1.0)
    pd = vmath("DOT_PRODUCT", p, d)
    pp = vmath("DOT_PRODUCT", p, p)
    disc = math_node("MAXIMUM", math_node("ADD", math_node("SUBTRACT", math_node("MULTIPLY", pd, pd), pp), 1.0), 0.0)
    u = math_node("SUBTRACT", pd, math_node("SQRT", disc))
    q = vmath("NORMALIZE", vmath("SUBTRACT", p, vmath("SCALE", d, scale=u)))
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(q, sep.inputs[0])
    lon = math_node("ARCTAN2", sep.outputs["Y"], sep.outputs["X"])
    u_tex = math_node("ADD", math_node("DIVIDE", lon, 2.0 * math.pi), 0.5)
    lat = math_node("ARCSINE", sep.outputs["Z"])
    v_tex = math_node("ADD", math_node("DIVIDE", lat, math.pi), 0.5)
    uv = nodes.new("ShaderNodeCombineXYZ")
    links.new(u_tex, uv.inputs["X"])
    links.new(v_tex, uv.inputs["Y"])
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = image
    tex.interpolation = "Linear"
    tex.extension = "EXTEND"
    links.new(uv.outputs["Vector"], tex.inputs["Vector"])
    emit = nodes.new("ShaderNodeEmission")
    emit.inputs["Strength"].default_value = 1.0
    links.new(tex.outputs["Color"], emit.inputs["Color"])
    # a camera outside the mesh sees its near side first: that side lets the ray through to the inside
    see_through = nodes.new("ShaderNodeBsdfTransparent")
    mix = nodes.new("ShaderNodeMixShader")
    links.new(geometry.outputs["Backfacing"], mix.inputs["Fac"])
    links.new(see_through.outputs["BSDF"], mix.inputs[1])
    links.new(emit.outputs["Emission"], mix.inputs[2])
    out = nodes.new("ShaderNodeOutputMaterial")
    links.new(mix.outputs["Shader"], out.inputs["Surface"])
    return mat


def import_background_sphere(result_dir, record: dict, collection, colour_mode: str = "EXACT"):
    """The sphere of `record` (metrics.json's plan.background_sphere) with the texture from `result_dir`."""
    import bmesh

    from gsgs_engine import GsgsError

    path = Path(result_dir) / str(record.get("file", "background_sphere.png"))
    if not path.is_file():
        raise GsgsError(f"{path}: the result's metrics.json names this background texture but it is missing; "
                        "copy it back beside point_cloud.ply or import the splats alone (Import Splat PLY)")
    try:
        centre = [float(x) for x in record["centre"]]
        radius = float(record["radius"])
    except (KeyError, TypeError, ValueError):
        raise GsgsError(f"{Path(result_dir) / 'metrics.json'}: plan.background_sphere has no valid centre and "
                        "radius; re-export the run") from None
    if len(centre) != 3 or not all(math.isfinite(x) for x in centre) or not (math.isfinite(radius) and radius > 0):
        raise GsgsError(f"{Path(result_dir) / 'metrics.json'}: plan.background_sphere's centre {centre} / radius "
                        f"{radius} is not a sphere; re-export the run")
    image = bpy.data.images.load(str(path), check_existing=False)
    image.colorspace_settings.name = _colourspace(colour_mode)
    mesh = bpy.data.meshes.new(OBJECT_NAME)
    bm = bmesh.new()
    bmesh.ops.create_uvsphere(bm, u_segments=SEGMENTS[0], v_segments=SEGMENTS[1], radius=MESH_RADIUS)
    bm.to_mesh(mesh)
    bm.free()
    mesh.materials.append(_material(image))
    obj = bpy.data.objects.new(OBJECT_NAME, mesh)
    obj.location = centre
    obj.scale = (radius, radius, radius)
    for attr in ("visible_diffuse", "visible_glossy", "visible_transmission", "visible_volume_scatter",
                 "visible_shadow"):
        if hasattr(obj, attr):
            setattr(obj, attr, False)  # seen by camera rays only: it lights nothing, as in the engine
    obj["gsgs_image"] = image.name
    obj["gsgs_background_sphere"] = json.dumps(record)
    collection.objects.link(obj)
    return obj


__all__ = ["OBJECT_NAME", "fit_clip_end", "import_background_sphere", "record_of", "set_colour_mode"]
