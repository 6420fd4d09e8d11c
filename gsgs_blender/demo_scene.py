"""The demo's procedural scene: textured objects on a ground disc, lights, a world colour, and a rig of
8 training and 25 test cameras on a hemisphere (NeRF-synthetic-like). bpy only, no external assets,
deterministic: the same call builds the same scene.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import bmesh
import bpy

from .dataset_render import SphereRig, add_rig_cameras

SCENE_VERSION = 2  # bump when the scene or rig changes: the demo re-renders datasets of another version
TRAIN_VIEWS = 8
TEST_VIEWS = 25
RIG_RADIUS = 4.5
TARGET = (0.0, 0.0, 0.35)
TRAIN_RIG = SphereRig(count=TRAIN_VIEWS, radius=RIG_RADIUS, target=TARGET, seed=0,
                      min_elevation_deg=15.0, max_elevation_deg=65.0)
# Test views interleave with the training ones (different seed -> different spiral phase) and reach a
# little lower and higher, so they measure novel-view quality rather than re-render training poses.
TEST_RIG = SphereRig(count=TEST_VIEWS, radius=RIG_RADIUS, target=TARGET, seed=1,
                     min_elevation_deg=10.0, max_elevation_deg=75.0)


@dataclass
class DemoScene:
    scene: bpy.types.Scene
    objects: list = field(default_factory=list)
    train_cameras: list = field(default_factory=list)
    test_cameras: list = field(default_factory=list)

    @property
    def splits(self) -> dict:
        return {"train": self.train_cameras, "test": self.test_cameras}


# -- materials: procedural textures with distinct colours, so photometric training sees texture --
def _material(name: str, texture: str, color_a, color_b, scale: float, roughness: float = 0.5):
    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:  # Blender < 5 creates materials without nodes
        mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    bsdf = nt.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Roughness"].default_value = roughness
    coords = nt.nodes.new("ShaderNodeTexCoord")
    if texture == "checker":
        tex = nt.nodes.new("ShaderNodeTexChecker")
        tex.inputs["Color1"].default_value = (*color_a, 1.0)
        tex.inputs["Color2"].default_value = (*color_b, 1.0)
        color = tex.outputs["Color"]
    elif texture == "brick":
        tex = nt.nodes.new("ShaderNodeTexBrick")
        tex.inputs["Color1"].default_value = (*color_a, 1.0)
        tex.inputs["Color2"].default_value = (*[0.8 * c for c in color_a], 1.0)
        tex.inputs["Mortar"].default_value = (*color_b, 1.0)
        tex.inputs["Mortar Size"].default_value = 0.03
        color = tex.outputs["Color"]
    else:  # noise / wave: a scalar pattern through a two-colour ramp
        if texture == "noise":
            tex = nt.nodes.new("ShaderNodeTexNoise")
            tex.inputs["Detail"].default_value = 4.0
        elif texture == "wave":
            tex = nt.nodes.new("ShaderNodeTexWave")
            tex.inputs["Distortion"].default_value = 4.0
            tex.inputs["Detail"].default_value = 2.0
        else:
            raise ValueError(f"unknown demo texture {texture!r}")
        ramp = nt.nodes.new("ShaderNodeValToRGB")
        ramp.color_ramp.elements[0].color = (*color_a, 1.0)
        ramp.color_ramp.elements[1].color = (*color_b, 1.0)
        # noise values cluster around 0.5: a narrow ramp keeps both colours visible instead of their grey mix
        ramp.color_ramp.elements[0].position = 0.38
        ramp.color_ramp.elements[1].position = 0.62
        nt.links.new(tex.outputs["Fac"], ramp.inputs["Fac"])
        color = ramp.outputs["Color"]
    tex.inputs["Scale"].default_value = scale
    nt.links.new(coords.outputs["Object"], tex.inputs["Vector"])
    nt.links.new(color, bsdf.inputs["Base Color"])
    nt.links.new(bsdf.outputs["BSDF"], out.inputs["Surface"])
    return mat


def _mesh_object(name: str, build, collection, material, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0),
                 smooth: bool = False):
    me = bpy.data.meshes.new(name)
    bm = bmesh.new()
    build(bm)
    bm.to_mesh(me)
    bm.free()
    if smooth:
        for poly in me.polygons:
            poly.use_smooth = True
    me.materials.append(material)
    obj = bpy.data.objects.new(name, me)
    obj.location = location
    obj.rotation_euler = rotation
    collection.objects.link(obj)
    return obj


def _collection(scene, name: str):
    coll = bpy.data.collections.new(name)
    scene.collection.children.link(coll)
    return coll


def build_demo_scene(scene: bpy.types.Scene | None = None, clear: bool = True) -> DemoScene:
    """Build the demo scene (into a fresh empty file when `clear`) and its 8 + 25 camera rig."""
    if clear:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = bpy.context.scene
    scene = scene or bpy.context.scene
    scene.name = "gsgs_demo"
    demo = DemoScene(scene)
    objs = _collection(scene, "gsgs demo objects")

    ground = _material("ground_brick", "brick", (0.55, 0.22, 0.12), (0.85, 0.82, 0.72), scale=1.5, roughness=0.8)
    checker = _material("cube_checker", "checker", (0.8, 0.08, 0.06), (0.92, 0.92, 0.88), scale=4.0)
    noise = _material("sphere_noise", "noise", (0.05, 0.15, 0.7), (0.95, 0.8, 0.1), scale=6.0, roughness=0.35)
    wave = _material("cylinder_wave", "wave", (0.1, 0.55, 0.15), (0.75, 0.1, 0.6), scale=3.0)
    cone_mat = _material("cone_checker", "checker", (0.05, 0.5, 0.55), (0.95, 0.55, 0.1), scale=6.0)
    monkey_mat = _material("monkey_noise", "noise", (0.9, 0.9, 0.85), (0.35, 0.1, 0.45), scale=3.0)

    demo.objects = [
        _mesh_object("ground", lambda bm: bmesh.ops.create_circle(bm, cap_ends=True, segments=64, radius=1.5),
                     objs, ground),
        _mesh_object("cube", lambda bm: bmesh.ops.create_cube(bm, size=0.6), objs, checker,
                     location=(-0.55, -0.35, 0.3), rotation=(0.0, 0.0, math.radians(30))),
        _mesh_object("sphere", lambda bm: bmesh.ops.create_uvsphere(bm, u_segments=48, v_segments=24, radius=0.38),
                     objs, noise, location=(0.55, -0.3, 0.38), smooth=True),
        _mesh_object("cylinder", lambda bm: bmesh.ops.create_cone(bm, cap_ends=True, segments=48, radius1=0.25,
                                                                   radius2=0.25, depth=0.9),
                     objs, wave, location=(0.15, 0.6, 0.45), smooth=True),
        _mesh_object("cone", lambda bm: bmesh.ops.create_cone(bm, cap_ends=True, segments=32, radius1=0.3,
                                                               radius2=0.0, depth=0.6),
                     objs, cone_mat, location=(-0.65, 0.55, 0.3)),
        _mesh_object("monkey", lambda bm: bmesh.ops.create_monkey(bm), objs, monkey_mat,
                     location=(-0.55, -0.35, 0.82), rotation=(0.0, 0.0, math.radians(-30)), smooth=True),
    ]
    demo.objects[-1].scale = (0.28, 0.28, 0.28)

    # lights: a warm key sun, a cool fill area light; the world colour adds soft ambient light
    sun = bpy.data.lights.new("sun", "SUN")
    sun.energy = 3.0
    sun.color = (1.0, 0.95, 0.85)
    sun.angle = math.radians(8.0)
    sun_obj = bpy.data.objects.new("sun", sun)
    sun_obj.rotation_euler = (math.radians(40), math.radians(10), math.radians(35))
    objs.objects.link(sun_obj)
    area = bpy.data.lights.new("fill", "AREA")
    area.energy = 150.0
    area.size = 2.0
    area.color = (0.8, 0.88, 1.0)
    area_obj = bpy.data.objects.new("fill", area)
    area_obj.location = (-2.5, 2.0, 2.5)
    area_obj.rotation_euler = (math.radians(-45), math.radians(-40), 0.0)
    objs.objects.link(area_obj)

    world = bpy.data.worlds.new("gsgs_demo_world")
    if world.node_tree is None:
        world.use_nodes = True
    bg = world.node_tree.nodes.get("Background") or world.node_tree.nodes.new("ShaderNodeBackground")
    bg.inputs["Color"].default_value = (0.55, 0.6, 0.7, 1.0)
    bg.inputs["Strength"].default_value = 0.45
    scene.world = world

    # predictable sRGB colours in the PNGs (AgX / Filmic would tone-map the textures)
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"

    demo.train_cameras = add_rig_cameras(TRAIN_RIG, "train", scene, _collection(scene, "gsgs train cameras"))
    demo.test_cameras = add_rig_cameras(TEST_RIG, "test", scene, _collection(scene, "gsgs test cameras"))
    scene.camera = demo.train_cameras[0]
    bpy.context.view_layer.update()
    return demo
