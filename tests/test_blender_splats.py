"""Gaussian PLY -> Blender splat object: attributes, geometry-nodes instances, other tools' PLYs, speed."""

from __future__ import annotations

import time

import numpy as np
import pytest

from gsgs_engine.cameras import quat_to_rotmat
from gsgs_engine.io.ply import GaussianPly, write_gaussian_ply

bpy = pytest.importorskip("bpy")
from gsgs_blender import node_groups, splat_import, splat_material  # noqa: E402  (needs bpy)

pytestmark = pytest.mark.blender


@pytest.fixture(autouse=True)
def empty_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _splats(n: int, degree: int, seed: int = 0) -> GaussianPly:
    rng = np.random.default_rng(seed)
    rest = {0: 0, 1: 3, 2: 8, 3: 15}[degree]
    return GaussianPly(positions=rng.normal(size=(n, 3)), opacity_logits=rng.normal(size=n) * 2,
                       log_scales=rng.normal(size=(n, 3)) - 3, quats_wxyz=rng.normal(size=(n, 4)),
                       sh_dc=rng.normal(size=(n, 3)), sh_rest=rng.normal(size=(n, rest, 3)) * 0.1)


def _attr(mesh, name: str, width: int) -> np.ndarray:
    attr = mesh.attributes[name]
    key = {"FLOAT": "value", "QUATERNION": "value", "FLOAT_VECTOR": "vector", "FLOAT_COLOR": "color",
           "FLOAT4X4": "value"}[attr.data_type]
    out = np.empty(len(attr.data) * width, np.float32)
    attr.data.foreach_get(key, out)
    return out.reshape(len(attr.data), width) if width > 1 else out


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_import_any_sh_degree(tmp_path, degree):
    g = _splats(300, degree)
    path = tmp_path / f"deg{degree}.ply"
    write_gaussian_ply(path, g)
    obj, seconds = splat_import.import_splats(path, max_display=0)
    mesh = obj.data
    assert len(mesh.vertices) == 300 and len(mesh.edges) == 0 and len(mesh.polygons) == 0
    assert obj["gsgs_sh_degree"] == degree
    np.testing.assert_allclose(_attr(mesh, "position", 3), g.positions, atol=1e-6)
    np.testing.assert_allclose(_attr(mesh, "opacity", 1), 1 / (1 + np.exp(-g.opacity_logits)), atol=1e-6)
    np.testing.assert_allclose(_attr(mesh, "scale", 3), np.exp(g.log_scales), rtol=1e-5)
    q = g.quats_wxyz / np.linalg.norm(g.quats_wxyz, axis=1, keepdims=True)
    np.testing.assert_allclose(_attr(mesh, "rotation", 4), q, atol=1e-6)
    rgb = splat_import.srgb_to_linear(np.clip(0.5 + splat_import.SH_C0 * g.sh_dc, 0, 1))  # linear, as Blender
    np.testing.assert_allclose(_attr(mesh, "color", 4)[:, :3], rgb, atol=1e-6)
    rank = _attr(mesh, "gsgs_lod_rank", 1)
    assert sorted(np.round(rank * 300).astype(int)) == list(range(300))  # a permutation: 0, 1/n, ...
    rest_names = sorted(a.name for a in mesh.attributes if a.name.startswith("sh_rest_"))
    assert len(rest_names) == {0: 0, 1: 3, 3: 15}[degree]
    for k, name in enumerate(rest_names):
        np.testing.assert_allclose(_attr(mesh, name, 3), g.sh_rest[:, k], atol=1e-6)


def test_geometry_nodes_instances_are_oriented_scaled_and_coloured(tmp_path):
    g = _splats(50, 1, seed=3)
    path = tmp_path / "s.ply"
    write_gaussian_ply(path, g)
    obj, _ = splat_import.import_splats(path, max_display=0, size=2.0)
    node_groups.set_modifier_input(obj.modifiers["GS-GS Splats"], "Dilation", 0.0)  # dilation: its own test
    obj.update_tag()
    depsgraph = bpy.context.evaluated_depsgraph_get()
    geometry = obj.evaluated_get(depsgraph).evaluated_geometry()  # keep it alive while reading
    instances = geometry.instances_pointcloud()
    assert len(instances.points) == 50
    m = _attr(instances, "instance_transform", 16).reshape(50, 4, 4).transpose(0, 2, 1)  # column-major
    expected_rs = quat_to_rotmat(g.quats_wxyz) * (2.0 * np.exp(g.log_scales))[:, None, :]
    np.testing.assert_allclose(m[:, :3, :3], expected_rs, atol=1e-5)
    np.testing.assert_allclose(m[:, :3, 3], g.positions, atol=1e-5)
    # Colour, opacity and proxy size reach the instance domain, where the material's Instancer attributes read them.
    np.testing.assert_allclose(_attr(instances, "opacity", 1), 1 / (1 + np.exp(-g.opacity_logits)), atol=1e-6)
    np.testing.assert_allclose(_attr(instances, "gsgs_proxy", 1), 2.0, atol=1e-6)
    assert _attr(instances, "gsgs_rgb", 3).shape == (50, 3)
    mat = bpy.data.materials[splat_material.MATERIAL_NAME]
    names = {n.attribute_name for n in mat.node_tree.nodes if n.bl_idname == "ShaderNodeAttribute"}
    assert names == {"gsgs_rgb", "opacity", "gsgs_proxy"}


def test_viewport_density_limit_keeps_full_data(tmp_path):
    g = _splats(2000, 0, seed=5)
    path = tmp_path / "s.ply"
    write_gaussian_ply(path, g)
    obj, _ = splat_import.import_splats(path, max_display=500)
    mod = obj.modifiers["GS-GS Splats"]
    assert node_groups.get_modifier_input(mod, "Display Ratio") == pytest.approx(0.25)
    assert len(obj.data.vertices) == 2000  # the mesh keeps everything
    depsgraph = bpy.context.evaluated_depsgraph_get()  # the bpy module evaluates for the viewport
    geometry = obj.evaluated_get(depsgraph).evaluated_geometry()
    instances = geometry.instances_pointcloud()
    shown = len(instances.points)
    assert 500 <= shown <= 501, shown
    # The most visible (opacity x footprint) are the ones shown, not a random subset.
    s = np.sort(np.exp(g.log_scales), axis=1)
    priority = 1 / (1 + np.exp(-g.opacity_logits)) * np.sqrt(s[:, 1] * s[:, 2])
    threshold = np.sort(priority)[::-1][shown - 1]
    shown_opacity = _attr(instances, "opacity", 1)
    assert len(shown_opacity) == shown
    assert (priority >= threshold - 1e-9).sum() == shown


def test_ply_with_reordered_and_extra_properties(tmp_path):
    """A PLY from another (4D) tool: properties in another order plus unknown per-point fields."""
    n = 40
    rng = np.random.default_rng(9)
    names = ["rot_0", "rot_1", "rot_2", "rot_3", "opacity", "t_center", "x", "y", "z", "scale_0", "scale_1",
             "scale_2", "f_dc_0", "f_dc_1", "f_dc_2", "motion_0", "motion_1", "motion_2"]
    rows = np.zeros(n, dtype=[(name, "<f4") for name in names])
    for name in names:
        rows[name] = rng.normal(size=n)
    header = "ply\nformat binary_little_endian 1.0\nelement vertex %d\n" % n
    header += "".join(f"property float {name}\n" for name in names) + "end_header\n"
    path = tmp_path / "other_tool.ply"
    path.write_bytes(header.encode() + rows.tobytes())

    obj, _ = splat_import.import_splats(path, max_display=0)
    mesh = obj.data
    np.testing.assert_allclose(_attr(mesh, "position", 3), np.stack([rows["x"], rows["y"], rows["z"]], 1), atol=1e-6)
    np.testing.assert_allclose(_attr(mesh, "opacity", 1), 1 / (1 + np.exp(-rows["opacity"])), atol=1e-6)
    np.testing.assert_allclose(_attr(mesh, "t_center", 1), rows["t_center"], atol=1e-6)
    np.testing.assert_allclose(_attr(mesh, "motion_2", 1), rows["motion_2"], atol=1e-6)
    assert obj["gsgs_sh_degree"] == 0
    assert list(obj["gsgs_temporal_fields"]) == ["motion_0", "motion_1", "motion_2", "t_center"]


def test_missing_file_is_a_clear_error(tmp_path):
    from gsgs_engine import GsgsError

    with pytest.raises(GsgsError, match="no such PLY"):
        splat_import.import_splats(tmp_path / "nope.ply")


@pytest.mark.slow
def test_million_splats_import_in_seconds(tmp_path):
    g = _splats(1_000_000, 3, seed=1)
    path = tmp_path / "million.ply"
    write_gaussian_ply(path, g)
    t0 = time.perf_counter()
    obj, seconds = splat_import.import_splats(path)
    wall = time.perf_counter() - t0
    print(f"\n1,000,000 splats (SH degree 3): import_splats {seconds:.2f} s (wall {wall:.2f} s)")
    assert len(obj.data.vertices) == 1_000_000
    assert seconds < 30.0


def test_render_shows_splat_colour_and_opacity(tmp_path, empty_scene):
    """Cycles render through the material: an opaque red splat renders red (alpha capped at 0.99 as the
    engine), a 50 % green one half green over black, each at the pixel the engine's camera projects its centre to."""
    from gsgs_blender import camera_convert
    from gsgs_engine.cameras import Camera, look_at

    scene = empty_scene
    try:
        scene.render.engine = "CYCLES"
    except TypeError:
        pytest.skip("Cycles is not in this Blender build")
    dc = lambda rgb: (np.array(rgb, float) - 0.5) / splat_import.SH_C0  # noqa: E731
    # (different depths: exactly coplanar faces of two proxies would let a ray see only one of them)
    g = GaussianPly(positions=[[-0.6, 0, 0], [0.6, 0.3, 0]], opacity_logits=[12.0, 0.0],
                    log_scales=np.log(np.full((2, 3), 0.4)), quats_wxyz=[[1, 0, 0, 0], [1, 0, 0, 0]],
                    sh_dc=[dc([1, 0, 0]), dc([0, 1, 0])], sh_rest=np.zeros((2, 0, 3)))
    write_gaussian_ply(tmp_path / "two.ply", g)
    splat_import.import_splats(tmp_path / "two.ply", max_display=0)
    R, t = look_at(np.array([0.0, -4.0, 0.0]), np.zeros(3))
    cam = Camera(R=R, t=t, fx=40, fy=40, cx=32, cy=16, width=64, height=32)
    cam_obj = camera_convert.new_camera_object(cam, scene.collection, scene)
    camera_convert.apply_camera_to_object(cam, cam_obj, scene, set_scene_frame=True)
    scene.camera = cam_obj
    from gsgs_blender import ops_setup

    ops_setup.set_up(scene, "LINEAR")  # linear colours: the EXR holds alpha x linear colour
    scene.cycles.device = "CPU"
    scene.world = None  # no world: a black background
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.filepath = str(tmp_path / "render.exr")
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(str(tmp_path / "render.exr"))
    px = np.array(img.pixels[:], dtype=np.float32).reshape(32, 64, 4)[::-1]  # Blender stores bottom row first
    (u_red, v_red), (u_green, v_green) = cam.project(np.asarray(g.positions))[0]
    np.testing.assert_allclose(px[int(v_red), int(u_red), :3], [0.99, 0.0, 0.0], atol=0.02)  # alpha cap 0.99
    np.testing.assert_allclose(px[int(v_green), int(u_green), :3], [0.0, 0.5, 0.0], atol=0.02)
    assert px[2, 32, :3].max() < 0.01  # background between and above the splats stays black
