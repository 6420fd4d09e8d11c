"""The geometry-nodes group that turns imported splat points into renderable Gaussian proxies.

Per point, for the scene's active (render) camera, exactly as the engine's rasteriser
(gsgs_engine/render/project.py) does per Gaussian:
  * colour: SH of degree 0-3 (whatever coefficients the PLY has: missing ones read as 0)
    along normalise(mean - camera centre), + 0.5, clamped at 0, then sRGB -> linear (the engine's
    colours are display values; Blender's Standard view transform encodes linear back to sRGB);
  * dilation: the engine adds 0.3 px^2 to every projected covariance. Adding the isotropic 3D
    variance 0.3 (z / f)^2 (z: camera depth of the mean, f: focal length in pixels) to the
    Gaussian projects to the same 0.3 px^2 (to first order), so each scale becomes
    sqrt(scale^2 + 0.3 (z / f)^2);
  * renders: the engine's 2D Gaussian itself. Each splat becomes one square facing the render
    camera, in the plane through its mean parallel to the image plane, carrying the EWA conic
    (inverse of J W Sigma W^T J^T + 0.3 px^2, in that plane's units) as `gsgs_conic`; the
    camera-plane material (splat_material.camera_plane_material) evaluates the engine's
    alpha = min(0.99, o exp(-d^T conic d / 2)) there. A ray meets these planes in the order of
    their camera depth, which is the engine's sort order, once per splat. The square spans the
    distance where the alpha falls to 1/255 along the major axis;
  * viewport (and renders with `Exact Projection` off): a cube of half-size `Size` dilated sigmas
    along the Gaussian's axes, carrying `gsgs_proxy` (the half-size in sigmas); the splat
    material computes the Gaussian alpha at each ray's closest approach. It looks right from any
    view (the camera planes only face the render camera).
Viewport level of detail: the viewport keeps the `Display Ratio` most visible splats (the
`gsgs_lod_rank` attribute the import writes: rank by opacity x size); renders draw all.
"""

from __future__ import annotations

import bpy

from . import splat_material
from .node_math import NodeMath, input_socket, output

GROUP_NAME = "GS-GS Splats"
MODIFIER_NAME = "GS-GS Splats"
GROUP_VERSION = 3  # bump when the graph changes so old files rebuild it
LOW_PASS_DILATION = 0.3  # px^2, gsgs_engine.render.project.LOW_PASS_DILATION (checked by a test)
# Viewport proxy half-size in sigmas: the engine's own 3-sigma screen radius (renders size each splat exactly).
DEFAULT_SIZE = 3.0
LOD_RANK = "gsgs_lod_rank"
FRUSTUM_SLACK = 1.3  # gsgs_engine.render.project.FRUSTUM_SLACK
NEAR = 0.01  # gsgs_engine.render.project.project_gaussians' default near plane
SH_REST_COUNT = 15  # degree 3

# Real SH basis of degree 0-3 with the 3DGS constants and signs (gsgs_engine/render/sh.py).
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)


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


def _named(nm: NodeMath, name: str, data_type: str):
    node = nm.node("GeometryNodeInputNamedAttribute", data_type=data_type)
    node.inputs["Name"].default_value = name
    return output(node, "Attribute")


def _store(nm: NodeMath, geometry, name: str, value, data_type: str):
    """Store `value` as the point attribute `name`; returns the geometry output."""
    node = nm.node("GeometryNodeStoreNamedAttribute", data_type=data_type, domain="POINT")
    node.inputs["Name"].default_value = name
    nm.tree.links.new(geometry, node.inputs["Geometry"])
    nm.tree.links.new(value, input_socket(node, "Value", "VECTOR" if data_type == "FLOAT_VECTOR" else "VALUE"))
    return node.outputs["Geometry"]


def sh_basis(nm: NodeMath, direction) -> list:
    """The 15 non-constant SH basis values (degree 1-3) of a unit direction, as float sockets."""
    x, y, z = nm.separate(direction)
    xx, yy, zz = nm.mul(x, x), nm.mul(y, y), nm.mul(z, z)
    xy, yz, xz = nm.mul(x, y), nm.mul(y, z), nm.mul(x, z)
    xx_plus_yy = nm.add(xx, yy)
    four_zz_minus = nm.sub(nm.mul(zz, 4.0), xx_plus_yy)  # 4 zz - xx - yy
    return [
        nm.mul(y, -SH_C1), nm.mul(z, SH_C1), nm.mul(x, -SH_C1),
        nm.mul(xy, SH_C2[0]), nm.mul(yz, SH_C2[1]), nm.mul(nm.sub(nm.mul(zz, 2.0), xx_plus_yy), SH_C2[2]),
        nm.mul(xz, SH_C2[3]), nm.mul(nm.sub(xx, yy), SH_C2[4]),
        nm.mul(nm.mul(y, nm.sub(nm.mul(xx, 3.0), yy)), SH_C3[0]),
        nm.mul(nm.mul(xy, z), SH_C3[1]),
        nm.mul(nm.mul(y, four_zz_minus), SH_C3[2]),
        nm.mul(nm.mul(z, nm.sub(nm.mul(zz, 2.0), nm.mul(xx_plus_yy, 3.0))), SH_C3[3]),
        nm.mul(nm.mul(x, four_zz_minus), SH_C3[4]),
        nm.mul(nm.mul(z, nm.sub(xx, yy)), SH_C3[5]),
        nm.mul(nm.mul(x, nm.sub(xx, nm.mul(yy, 3.0))), SH_C3[6]),
    ]


def view_color(nm: NodeMath, direction, linearise):
    """max(0, SH(direction) + 0.5) from `sh_dc`, `sh_rest_01..15` (absent ones count as 0); converted
    from sRGB to linear as far as the `linearise` socket (0..1) says."""
    total = nm.vmath("SCALE", _named(nm, "sh_dc", "FLOAT_VECTOR"), scale=SH_C0)
    for k, basis in enumerate(sh_basis(nm, direction), start=1):
        term = nm.vmath("SCALE", _named(nm, f"sh_rest_{k:02d}", "FLOAT_VECTOR"), scale=basis)
        total = nm.vmath("ADD", total, term)
    display = nm.vmath("MAXIMUM", nm.vmath("ADD", total, (0.5, 0.5, 0.5)), (0.0, 0.0, 0.0))
    change = nm.vmath("SUBTRACT", nm.srgb_to_linear_rgb(display), display)
    return nm.vmath("ADD", display, nm.vmath("SCALE", change, scale=linearise))


def splat_node_group() -> bpy.types.GeometryNodeTree:
    """Build (once per file) the group: points -> dilated, coloured Gaussian proxy cubes."""
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
            "fraction of the splats drawn in the viewport, most visible (opacity x size) first; renders draw all")
    _socket(group, "Size", "INPUT", "NodeSocketFloat", DEFAULT_SIZE, 0.5, 10.0,
            "viewport proxy half-size in standard deviations: the Gaussian is cut where the proxy ends "
            "(renders with Exact Projection size each splat where its alpha reaches 1/255)")
    _socket(group, "Render Width", "INPUT", "NodeSocketFloat", 0.0, 0.0, 1e6,
            "render width in pixels (driven by the scene's resolution): sets the 0.3 px^2 screen-space "
            "dilation the engine trains with; 0 turns the dilation off")
    _socket(group, "Dilation", "INPUT", "NodeSocketFloat", LOW_PASS_DILATION, 0.0, 10.0,
            "screen-space variance added to every splat, in pixels^2 (the engine uses 0.3)")
    _socket(group, "Linear Colours", "INPUT", "NodeSocketBool", False, description=(
        "on: colours converted from the engine's sRGB values to scene-linear (for the Standard view "
        "transform; blending then happens in linear light). Off: colours kept as display values, which "
        "blend exactly as the engine does under the Raw view transform (the import's render set-up sets it)"))
    _socket(group, "Exact Projection", "INPUT", "NodeSocketBool", True, description=(
        "renders draw each splat as the engine's projected 2D Gaussian on a plane facing the render camera "
        "(exact sort order and shape); off: the viewport's 3D proxies render too"))
    _socket(group, "Material", "INPUT", "NodeSocketMaterial")
    _socket(group, "Camera Material", "INPUT", "NodeSocketMaterial")
    _socket(group, "Geometry", "OUTPUT", "NodeSocketGeometry")

    nodes, links = group.nodes, group.links
    nm = NodeMath(group, -1600, 600)
    gin = nodes.new("NodeGroupInput")
    gin.location = (-2000, 0)
    gout = nodes.new("NodeGroupOutput")
    gout.location = (800, 0)

    # Viewport level of detail: drop points ranked past the ratio (rank 0 = most visible).
    is_viewport = nm.node("GeometryNodeIsViewport")
    beyond = nm.math("GREATER_THAN", _named(nm, LOD_RANK, "FLOAT"), gin.outputs["Display Ratio"])
    drop = nm.math("MULTIPLY", beyond, output(is_viewport, "Is Viewport"))
    delete = nm.node("GeometryNodeDeleteGeometry", domain="POINT")
    links.new(gin.outputs["Geometry"], delete.inputs["Geometry"])
    links.new(drop, delete.inputs["Selection"])

    # The render camera: centre, forward axis and focal length in pixels.
    active = nm.node("GeometryNodeInputActiveCamera")
    cam_obj = nm.node("GeometryNodeObjectInfo", transform_space="ORIGINAL")
    links.new(active.outputs[0], cam_obj.inputs["Object"])
    cam_info = nm.node("GeometryNodeCameraInfo")
    links.new(active.outputs[0], cam_info.inputs["Camera"])
    proj = nm.node("FunctionNodeSeparateMatrix")
    links.new(output(cam_info, "Projection Matrix"), proj.inputs["Matrix"])
    focal_px = nm.mul(output(proj, "Column 1 Row 1"), nm.mul(gin.outputs["Render Width"], 0.5))
    forward = nm.node("FunctionNodeRotateVector")
    forward.inputs["Vector"].default_value = (0.0, 0.0, -1.0)
    links.new(output(cam_obj, "Rotation"), forward.inputs["Rotation"])

    position = output(nm.node("GeometryNodeInputPosition"), "Position")
    offset = nm.vmath("SUBTRACT", position, output(cam_obj, "Location"))
    depth = nm.vmath("DOT_PRODUCT", offset, output(forward, "Vector"))
    pixel = nm.div(depth, focal_px)  # world size of one pixel at the mean (0 without a width)
    extra_var = nm.mul(gin.outputs["Dilation"], nm.mul(pixel, pixel))
    scale = _named(nm, "scale", "FLOAT_VECTOR")
    var = nm.vmath("ADD", nm.vmath("MULTIPLY", scale, scale), nm.combine(extra_var, extra_var, extra_var))
    dilated = nm.vmath("POWER", var, (0.5, 0.5, 0.5))
    proxy_scale = nm.vmath("SCALE", dilated, scale=gin.outputs["Size"])

    direction = nm.vmath("NORMALIZE", offset)
    rgb = view_color(nm, direction, gin.outputs["Linear Colours"])

    coloured = _store(nm, delete.outputs["Geometry"], splat_material.COLOR_ATTRIBUTE, rgb, "FLOAT_VECTOR")
    sized = _store(nm, coloured, splat_material.PROXY_ATTRIBUTE, gin.outputs["Size"], "FLOAT")

    cube = nm.node("GeometryNodeMeshCube")
    cube.inputs["Size"].default_value = (2.0, 2.0, 2.0)  # half-size 1: the material reads +-1 object coords
    set_mat = nm.node("GeometryNodeSetMaterial")
    links.new(cube.outputs["Mesh"], set_mat.inputs["Geometry"])
    links.new(gin.outputs["Material"], set_mat.inputs["Material"])

    instance = nodes.new("GeometryNodeInstanceOnPoints")
    instance.location = (400, 0)
    links.new(sized, instance.inputs["Points"])
    links.new(set_mat.outputs["Geometry"], instance.inputs["Instance"])
    links.new(_named(nm, "rotation", "QUATERNION"), instance.inputs["Rotation"])
    links.new(proxy_scale, instance.inputs["Scale"])
    # Point attributes (gsgs_rgb, opacity, gsgs_proxy, ...) propagate to the instance domain by themselves.

    planes = camera_planes(nm, gin, coloured, cam_obj, proj, offset, focal_px)
    use_cubes = nm.node("FunctionNodeBooleanMath", operation="NIMPLY")  # viewport, or not exact
    links.new(gin.outputs["Exact Projection"], use_cubes.inputs[0])
    links.new(output(is_viewport, "Is Viewport"), use_cubes.inputs[1])
    choose_planes = nm.node("GeometryNodeSwitch", input_type="GEOMETRY")
    links.new(use_cubes.outputs[0], choose_planes.inputs["Switch"])
    links.new(instance.outputs["Instances"], choose_planes.inputs["False"])
    links.new(planes, choose_planes.inputs["True"])
    links.new(choose_planes.outputs[0], gout.inputs["Geometry"])
    return group


def camera_planes(nm: NodeMath, gin, points, cam_obj, proj, offset, focal_px):
    """Points -> one camera-facing square per splat carrying the engine's EWA conic (project.py).

    In camera axes (x right, y down, z forward) a Gaussian axis a_i = sigma_i R e_i has components
    (ax, ay, az); the projection's Jacobian at the mean (tx = x/z, ty = y/z, clamped to 1.3x the
    half-field as the engine does) maps it onto the plane at depth z as (ax - tx az, ay - ty az), so
    in that plane's world units the covariance is sum_i v_i v_i^T + 0.3 (z / f)^2 I.
    """
    links = nm.tree.links
    rot_cam = output(cam_obj, "Rotation")

    def rotate(vector, rotation):
        node = nm.node("FunctionNodeRotateVector")
        node.inputs["Vector"].default_value = vector
        links.new(rotation, node.inputs["Rotation"])
        return output(node, "Vector")

    right, up, back = (rotate(axis, rot_cam) for axis in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)))
    down = nm.vmath("SCALE", up, scale=-1.0)
    forward = nm.vmath("SCALE", back, scale=-1.0)
    x = nm.vmath("DOT_PRODUCT", offset, right)
    y = nm.vmath("DOT_PRODUCT", offset, down)
    z = nm.vmath("DOT_PRODUCT", offset, forward)
    half_x = nm.div(1.0, output(proj, "Column 1 Row 1"))  # tan of the half field of view (centred camera)
    half_y = nm.div(1.0, output(proj, "Column 2 Row 2"))
    tx = nm.math("MINIMUM", nm.math("MAXIMUM", nm.div(x, z), nm.mul(half_x, -FRUSTUM_SLACK)),
                 nm.mul(half_x, FRUSTUM_SLACK))
    ty = nm.math("MINIMUM", nm.math("MAXIMUM", nm.div(y, z), nm.mul(half_y, -FRUSTUM_SLACK)),
                 nm.mul(half_y, FRUSTUM_SLACK))
    quat = _named(nm, "rotation", "QUATERNION")
    scale = _named(nm, "scale", "FLOAT_VECTOR")
    sx, sy, sz = nm.separate(scale)
    pixel = nm.div(z, focal_px)
    dil = nm.mul(gin.outputs["Dilation"], nm.mul(pixel, pixel))
    a_cov, b_cov, c_cov = dil, None, dil
    for axis, sigma in (((1.0, 0.0, 0.0), sx), ((0.0, 1.0, 0.0), sy), ((0.0, 0.0, 1.0), sz)):
        a_i = nm.vmath("SCALE", rotate(axis, quat), scale=sigma)
        az = nm.vmath("DOT_PRODUCT", a_i, forward)
        vx = nm.sub(nm.vmath("DOT_PRODUCT", a_i, right), nm.mul(tx, az))
        vy = nm.sub(nm.vmath("DOT_PRODUCT", a_i, down), nm.mul(ty, az))
        a_cov = nm.add(a_cov, nm.mul(vx, vx))
        b_cov = nm.mul(vx, vy) if b_cov is None else nm.add(b_cov, nm.mul(vx, vy))
        c_cov = nm.add(c_cov, nm.mul(vy, vy))
    det = nm.sub(nm.mul(a_cov, c_cov), nm.mul(b_cov, b_cov))
    conic = nm.combine(nm.div(c_cov, det), nm.div(nm.mul(b_cov, -1.0), det), nm.div(a_cov, det))
    mid = nm.mul(nm.add(a_cov, c_cov), 0.5)
    lam_max = nm.add(mid, nm.math("SQRT", nm.math("MAXIMUM", nm.sub(nm.mul(mid, mid), det), 0.0)))
    # Half-size where opacity x exp(-r^2 / 2 lambda) reaches 1/255 (0 for a splat that never does).
    opacity = _named(nm, "opacity", "FLOAT")
    reach = nm.mul(2.0, nm.math("LOGARITHM", nm.math("MAXIMUM", nm.mul(opacity, 255.0), 1.0), 2.718281828459045))
    radius = nm.math("SQRT", nm.mul(reach, lam_max))

    keep = nm.math("GREATER_THAN", z, NEAR)  # the engine culls means closer than its near plane
    delete = nm.node("GeometryNodeDeleteGeometry", domain="POINT")
    links.new(points, delete.inputs["Geometry"])
    links.new(nm.math("LESS_THAN", keep, 0.5), delete.inputs["Selection"])
    with_conic = _store(nm, delete.outputs["Geometry"], splat_material.CONIC_ATTRIBUTE, conic, "FLOAT_VECTOR")
    with_radius = _store(nm, with_conic, splat_material.PROXY_ATTRIBUTE, radius, "FLOAT")

    square = nm.node("GeometryNodeMeshGrid")
    square.inputs["Size X"].default_value = 2.0  # +-1 object coordinates, scaled by the radius
    square.inputs["Size Y"].default_value = 2.0
    square.inputs["Vertices X"].default_value = 2
    square.inputs["Vertices Y"].default_value = 2
    set_mat = nm.node("GeometryNodeSetMaterial")
    links.new(square.outputs["Mesh"], set_mat.inputs["Geometry"])
    links.new(gin.outputs["Camera Material"], set_mat.inputs["Material"])
    instance = nm.node("GeometryNodeInstanceOnPoints")
    links.new(with_radius, instance.inputs["Points"])
    links.new(set_mat.outputs["Geometry"], instance.inputs["Instance"])
    links.new(rot_cam, instance.inputs["Rotation"])
    links.new(nm.combine(radius, radius, 1.0), instance.inputs["Scale"])
    return instance.outputs["Instances"]


def add_splat_modifier(obj, display_ratio: float = 1.0, size: float = DEFAULT_SIZE, scene=None):
    """Attach the splat group to `obj` (a vertices-only mesh with splat attributes); the render width
    follows the scene's resolution through a driver."""
    mod = obj.modifiers.get(MODIFIER_NAME) or obj.modifiers.new(MODIFIER_NAME, "NODES")
    mod.node_group = splat_node_group()
    set_modifier_input(mod, "Display Ratio", float(display_ratio))
    set_modifier_input(mod, "Size", float(size))
    set_modifier_input(mod, "Material", splat_material.splat_material())
    set_modifier_input(mod, "Camera Material", splat_material.camera_plane_material())
    drive_render_width(obj, mod, scene or bpy.context.scene)
    return mod


def _identifier(mod, name: str) -> str:
    for item in mod.node_group.interface.items_tree:
        if getattr(item, "in_out", None) == "INPUT" and item.name == name:
            return item.identifier
    raise KeyError(f"the GS-GS node group has no input {name!r}")


def drive_render_width(obj, mod, scene) -> None:
    """Render Width = resolution_x x percentage / 100 of `scene`, as a Python-free driver."""
    path = f'modifiers["{mod.name}"]["{_identifier(mod, "Render Width")}"]'
    obj.driver_remove(path)
    fcurve = obj.driver_add(path)
    driver = fcurve.driver
    driver.type = "SCRIPTED"
    for var_name, data_path in (("width", "render.resolution_x"), ("percent", "render.resolution_percentage")):
        var = driver.variables.new()
        var.name = var_name
        var.type = "SINGLE_PROP"
        var.targets[0].id_type = "SCENE"
        var.targets[0].id = scene
        var.targets[0].data_path = data_path
    driver.expression = "width * percent / 100"  # a simple expression: no Python needed to evaluate it
    set_modifier_input(mod, "Render Width", scene.render.resolution_x * scene.render.resolution_percentage / 100)


def set_modifier_input(mod, name: str, value) -> None:
    mod[_identifier(mod, name)] = value


def get_modifier_input(mod, name: str):
    return mod[_identifier(mod, name)]
