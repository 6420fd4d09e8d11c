"""The geometry-nodes group and material that display imported splats.

Each point of the splat mesh becomes an ico-sphere instance rotated by its `rotation`
(QUATERNION attribute), scaled by `scale` x a size factor, carrying `color` and `opacity`
to the instance domain where the material reads them (Attribute node, Instancer type).
In the viewport a random subset (the Display Ratio) is shown; renders use every point, so
the full data stays on the mesh.
"""

from __future__ import annotations

import bpy

GROUP_NAME = "GS-GS Splats"
MATERIAL_NAME = "GS-GS Splat"
GROUP_VERSION = 2  # bump when the graph changes so old files rebuild it


def _socket(group, name: str, in_out: str, socket_type: str, default=None, min_value=None, max_value=None,
            description: str = ""):
    sock = group.interface.new_socket(name=name, in_out=in_out, socket_type=socket_type, description=description)
    if default is not None:
        sock.default_value = default
    if min_value is not None:
        sock.min_value = min_value
    if max_value is not None:
        sock.max_value = max_value
    return sock


def _output(node, name: str, socket_type: str | None = None):
    """A node output by name (and type: some nodes keep one hidden output per data type)."""
    for out in node.outputs:
        if out.name == name and (socket_type is None or out.type == socket_type) and out.enabled:
            return out
    raise KeyError(f"{node.bl_idname} has no enabled output {name!r} of type {socket_type}")


def _input(node, name: str, socket_type: str | None = None):
    for inp in node.inputs:
        if inp.name == name and (socket_type is None or inp.type == socket_type) and inp.enabled:
            return inp
    raise KeyError(f"{node.bl_idname} has no enabled input {name!r} of type {socket_type}")


def splat_material() -> bpy.types.Material:
    """Emission coloured by the splat colour, mixed with transparency by its opacity (front faces)."""
    mat = bpy.data.materials.get(MATERIAL_NAME)
    if mat is not None and mat.get("gsgs_version") == GROUP_VERSION:
        return mat
    if mat is None:
        mat = bpy.data.materials.new(MATERIAL_NAME)
    mat["gsgs_version"] = GROUP_VERSION
    tree = mat.node_tree
    tree.nodes.clear()
    nodes, links = tree.nodes, tree.links
    color = nodes.new("ShaderNodeAttribute")
    color.attribute_type, color.attribute_name = "INSTANCER", "color"
    color.location = (-600, 100)
    opacity = nodes.new("ShaderNodeAttribute")
    opacity.attribute_type, opacity.attribute_name = "INSTANCER", "opacity"
    opacity.location = (-600, 350)
    emission = nodes.new("ShaderNodeEmission")
    emission.location = (-300, 0)
    transparent = nodes.new("ShaderNodeBsdfTransparent")
    transparent.location = (-300, 200)
    mix = nodes.new("ShaderNodeMixShader")
    mix.location = (0, 150)
    out = nodes.new("ShaderNodeOutputMaterial")
    out.location = (250, 150)
    # Only the front of each proxy sphere shows the splat: a ray through a sphere crosses two
    # surfaces, and counting opacity on both would turn alpha a into 1 - (1 - a)^2.
    geometry = nodes.new("ShaderNodeNewGeometry")
    geometry.location = (-800, 500)
    front = nodes.new("ShaderNodeMath")
    front.operation = "SUBTRACT"
    front.inputs[0].default_value = 1.0
    front.location = (-600, 550)
    alpha = nodes.new("ShaderNodeMath")
    alpha.operation = "MULTIPLY"
    alpha.location = (-300, 400)
    links.new(geometry.outputs["Backfacing"], front.inputs[1])
    links.new(_output(opacity, "Factor"), alpha.inputs[0])
    links.new(front.outputs["Value"], alpha.inputs[1])
    links.new(_output(color, "Color"), emission.inputs["Color"])
    links.new(alpha.outputs["Value"], mix.inputs[0])
    links.new(transparent.outputs["BSDF"], mix.inputs[1])
    links.new(emission.outputs["Emission"], mix.inputs[2])
    links.new(mix.outputs["Shader"], out.inputs["Surface"])
    # Splats overlap heavily: blended transparency, no shadows from the proxy spheres.
    mat.surface_render_method = "BLENDED"
    if hasattr(mat, "use_transparency_overlap"):
        mat.use_transparency_overlap = True
    mat.diffuse_color = (0.8, 0.8, 0.8, 1.0)
    return mat


def splat_node_group() -> bpy.types.GeometryNodeTree:
    """Build (once per file) the group: points -> oriented, scaled, coloured ico-sphere instances."""
    group = bpy.data.node_groups.get(GROUP_NAME)
    if group is not None and group.get("gsgs_version") == GROUP_VERSION:
        return group
    if group is None:
        group = bpy.data.node_groups.new(GROUP_NAME, "GeometryNodeTree")
    group["gsgs_version"] = GROUP_VERSION
    group.nodes.clear()
    group.interface.clear()
    _socket(group, "Geometry", "INPUT", "NodeSocketGeometry")
    _socket(group, "Display Ratio", "INPUT", "NodeSocketFloat", 1.0, 0.0, 1.0,
            "fraction of the splats drawn in the viewport (renders draw all)")
    _socket(group, "Size", "INPUT", "NodeSocketFloat", 1.0, 0.0, 10.0,
            "sphere radius in standard deviations of each Gaussian")
    _socket(group, "Detail", "INPUT", "NodeSocketInt", 1, 1, 4, "ico-sphere subdivisions")
    _socket(group, "Material", "INPUT", "NodeSocketMaterial")
    _socket(group, "Geometry", "OUTPUT", "NodeSocketGeometry")

    nodes, links = group.nodes, group.links
    gin = nodes.new("NodeGroupInput")
    gin.location = (-1000, 0)
    gout = nodes.new("NodeGroupOutput")
    gout.location = (800, 0)

    # Viewport subset: delete a point when in the viewport and its random draw says "hide".
    is_viewport = nodes.new("GeometryNodeIsViewport")
    is_viewport.location = (-800, -250)
    keep = nodes.new("FunctionNodeRandomValue")
    keep.data_type = "BOOLEAN"
    keep.location = (-800, -400)
    keep.inputs["Seed"].default_value = 0
    links.new(gin.outputs["Display Ratio"], _input(keep, "Probability"))
    drop = nodes.new("FunctionNodeBooleanMath")
    drop.operation = "NIMPLY"  # viewport AND NOT keep
    drop.location = (-600, -300)
    links.new(is_viewport.outputs[0], drop.inputs[0])
    links.new(_output(keep, "Value", "BOOLEAN"), drop.inputs[1])
    delete = nodes.new("GeometryNodeDeleteGeometry")
    delete.domain = "POINT"
    delete.location = (-400, 0)
    links.new(gin.outputs["Geometry"], delete.inputs["Geometry"])
    links.new(drop.outputs[0], delete.inputs["Selection"])

    ico = nodes.new("GeometryNodeMeshIcoSphere")
    ico.location = (-400, -300)
    ico.inputs["Radius"].default_value = 1.0
    links.new(gin.outputs["Detail"], ico.inputs["Subdivisions"])
    set_mat = nodes.new("GeometryNodeSetMaterial")
    set_mat.location = (-200, -300)
    links.new(ico.outputs["Mesh"], set_mat.inputs["Geometry"])
    links.new(gin.outputs["Material"], set_mat.inputs["Material"])

    rotation = nodes.new("GeometryNodeInputNamedAttribute")
    rotation.data_type = "QUATERNION"
    rotation.inputs["Name"].default_value = "rotation"
    rotation.location = (-400, -550)
    scale = nodes.new("GeometryNodeInputNamedAttribute")
    scale.data_type = "FLOAT_VECTOR"
    scale.inputs["Name"].default_value = "scale"
    scale.location = (-400, -750)
    sized = nodes.new("ShaderNodeVectorMath")
    sized.operation = "SCALE"
    sized.location = (-200, -750)
    links.new(_output(scale, "Attribute"), sized.inputs[0])
    links.new(gin.outputs["Size"], _input(sized, "Scale"))

    instance = nodes.new("GeometryNodeInstanceOnPoints")
    instance.location = (100, 0)
    links.new(delete.outputs["Geometry"], instance.inputs["Points"])
    links.new(set_mat.outputs["Geometry"], instance.inputs["Instance"])
    links.new(_output(rotation, "Attribute"), instance.inputs["Rotation"])
    links.new(sized.outputs["Vector"], instance.inputs["Scale"])
    # Point attributes (color, opacity, SH, ...) propagate to the instance domain by themselves.
    links.new(instance.outputs["Instances"], gout.inputs["Geometry"])
    return group


def add_splat_modifier(obj, display_ratio: float = 1.0, size: float = 1.0, detail: int = 1):
    """Attach the splat display group to `obj` (a vertices-only mesh with splat attributes)."""
    mod = obj.modifiers.get("GS-GS Splats") or obj.modifiers.new("GS-GS Splats", "NODES")
    mod.node_group = splat_node_group()
    set_modifier_input(mod, "Display Ratio", float(display_ratio))
    set_modifier_input(mod, "Size", float(size))
    set_modifier_input(mod, "Detail", int(detail))
    set_modifier_input(mod, "Material", splat_material())
    return mod


def set_modifier_input(mod, name: str, value) -> None:
    for item in mod.node_group.interface.items_tree:
        if getattr(item, "in_out", None) == "INPUT" and item.name == name:
            mod[item.identifier] = value
            return
    raise KeyError(f"the GS-GS node group has no input {name!r}")


def get_modifier_input(mod, name: str):
    for item in mod.node_group.interface.items_tree:
        if getattr(item, "in_out", None) == "INPUT" and item.name == name:
            return mod[item.identifier]
    raise KeyError(f"the GS-GS node group has no input {name!r}")
