"""The splat materials: the engine's Gaussian alpha on each splat's proxy (Cycles and EEVEE).

Renders (camera_plane_material): each splat is a square facing the render camera through its mean
(node_groups.camera_planes), +-1 in object coordinates = +-`gsgs_proxy` world units along the
camera's right and up axes. With d = gsgs_proxy (x, -y) (camera axes: y points down) and the EWA
conic (A, B, C) = `gsgs_conic` in the same units, the alpha is the engine's
(gsgs_engine/render/reference.py): min(0.99, opacity exp(-(A dx^2 + C dy^2) / 2 - B dx dy)),
zero below 1/255.

Viewport (splat_material):
A proxy cube (node_groups.py) spans +-1 in object coordinates, which is +-`gsgs_proxy`
dilated sigmas along the Gaussian's axes. For the ray that hits the front face at object
point p with object-space direction d, the squared Mahalanobis distance of the ray's closest
approach to the Gaussian's mean is

    m^2 = s^2 (|p|^2 - (p . d)^2 / |d|^2),   s = gsgs_proxy,

and the splat's alpha is the engine's (gsgs_engine/render/reference.py):
alpha = min(0.99, opacity exp(-m^2 / 2)), zero below 1/255. The colour `gsgs_rgb` is already
linear and view-dependent (from the geometry nodes). Back faces are fully transparent, so a
ray crossing a proxy counts the Gaussian once.
"""

from __future__ import annotations

import bpy

from .node_math import NodeMath, output

MATERIAL_NAME = "GS-GS Splat"
CAMERA_MATERIAL_NAME = "GS-GS Splat (render camera)"
CONIC_ATTRIBUTE = "gsgs_conic"
MATERIAL_VERSION = 3
COLOR_ATTRIBUTE = "gsgs_rgb"
PROXY_ATTRIBUTE = "gsgs_proxy"
ALPHA_MAX = 0.99  # gsgs_engine.render.reference.ALPHA_MAX (checked by a test)
ALPHA_MIN = 1.0 / 255.0  # gsgs_engine.render.reference.ALPHA_MIN


def _instancer_attribute(nm: NodeMath, name: str):
    node = nm.node("ShaderNodeAttribute", attribute_type="INSTANCER", attribute_name=name)
    return node


def gaussian_alpha(nm: NodeMath):
    """The alpha socket: the Gaussian's opacity at the ray's closest approach, cut and capped as the engine."""
    coords = nm.node("ShaderNodeTexCoord")
    p = output(coords, "Object")
    geometry = nm.node("ShaderNodeNewGeometry")
    to_object = nm.node("ShaderNodeVectorTransform", vector_type="VECTOR", convert_from="WORLD",
                        convert_to="OBJECT")
    nm.tree.links.new(output(geometry, "Incoming"), to_object.inputs["Vector"])
    d = to_object.outputs["Vector"]
    pp = nm.vmath("DOT_PRODUCT", p, p)
    pd = nm.vmath("DOT_PRODUCT", p, d)
    dd = nm.vmath("DOT_PRODUCT", d, d)
    size = output(_instancer_attribute(nm, PROXY_ATTRIBUTE), "Factor")
    m2 = nm.mul(nm.mul(size, size), nm.math("MAXIMUM", nm.sub(pp, nm.div(nm.mul(pd, pd), dd)), 0.0))
    opacity = output(_instancer_attribute(nm, "opacity"), "Factor")
    alpha = nm.math("MINIMUM", nm.mul(opacity, nm.math("EXPONENT", nm.mul(m2, -0.5))), ALPHA_MAX)
    kept = nm.math("GREATER_THAN", alpha, ALPHA_MIN - 1e-7)  # alpha >= 1/255, as the engine
    front = nm.sub(1.0, output(geometry, "Backfacing"))
    return nm.mul(alpha, nm.mul(kept, front))


def conic_alpha(nm: NodeMath):
    """The alpha socket of a camera-facing square: the engine's 2D Gaussian, cut and capped as the engine."""
    p = output(nm.node("ShaderNodeTexCoord"), "Object")
    px, py, _ = nm.separate(p)
    size = output(_instancer_attribute(nm, PROXY_ATTRIBUTE), "Factor")
    dx = nm.mul(px, size)
    dy = nm.mul(py, nm.mul(size, -1.0))
    ca, cb, cc = nm.separate(output(_instancer_attribute(nm, CONIC_ATTRIBUTE), "Vector"))
    quad = nm.add(nm.mul(ca, nm.mul(dx, dx)), nm.mul(cc, nm.mul(dy, dy)))
    power = nm.sub(nm.mul(quad, -0.5), nm.mul(cb, nm.mul(dx, dy)))
    opacity = output(_instancer_attribute(nm, "opacity"), "Factor")
    alpha = nm.math("MINIMUM", nm.mul(opacity, nm.math("EXPONENT", nm.math("MINIMUM", power, 0.0))), ALPHA_MAX)
    kept = nm.math("GREATER_THAN", alpha, ALPHA_MIN - 1e-7)
    return nm.mul(alpha, kept)


def splat_material() -> bpy.types.Material:
    """Viewport proxies: the splat's colour mixed with transparency by the per-ray Gaussian alpha."""
    return _material(MATERIAL_NAME, gaussian_alpha, backface_culling=True)


def camera_plane_material() -> bpy.types.Material:
    """Render squares facing the camera: the splat's colour mixed with transparency by the engine's 2D alpha."""
    return _material(CAMERA_MATERIAL_NAME, conic_alpha, backface_culling=False)


def _material(name: str, alpha_fn, backface_culling: bool) -> bpy.types.Material:
    mat = bpy.data.materials.get(name)
    if mat is not None and mat.get("gsgs_version") == MATERIAL_VERSION:
        return mat
    if mat is None:
        mat = bpy.data.materials.new(name)
    mat["gsgs_version"] = MATERIAL_VERSION
    if mat.node_tree is None:  # Blender < 5 creates the tree only on request
        mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    nm = NodeMath(tree, -900, 600)
    alpha = alpha_fn(nm)
    color = _instancer_attribute(nm, COLOR_ATTRIBUTE)
    emission = nm.node("ShaderNodeEmission")
    tree.links.new(output(color, "Color"), emission.inputs["Color"])
    emission.inputs["Strength"].default_value = 1.0
    transparent = nm.node("ShaderNodeBsdfTransparent")
    mix = nm.node("ShaderNodeMixShader")
    tree.links.new(alpha, mix.inputs[0])
    tree.links.new(transparent.outputs["BSDF"], mix.inputs[1])
    tree.links.new(emission.outputs["Emission"], mix.inputs[2])
    out = tree.nodes.new("ShaderNodeOutputMaterial")
    out.location = (300, 0)
    tree.links.new(mix.outputs["Shader"], out.inputs["Surface"])
    # Splats overlap heavily: blended transparency (EEVEE), no light emitted onto other objects
    # (Cycles would otherwise build a light tree over every proxy face).
    mat.surface_render_method = "BLENDED"
    if hasattr(mat, "use_transparency_overlap"):
        mat.use_transparency_overlap = True
    mat.use_backface_culling = backface_culling
    if hasattr(mat, "cycles") and hasattr(mat.cycles, "emission_sampling"):
        mat.cycles.emission_sampling = "NONE"
    mat.diffuse_color = (0.8, 0.8, 0.8, 1.0)
    return mat
