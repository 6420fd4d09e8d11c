"""Set Up Splat Rendering: the render settings under which splats look like the engine's render."""

from __future__ import annotations

import bpy

from . import node_groups, render_setup
from .render_setup import COLOUR_ITEMS



def splat_objects(scene) -> list:
    """Objects of `scene` that carry the GS-GS splat modifier."""
    return [o for o in scene.objects
            if o.type == "MESH" and (m := o.modifiers.get(node_groups.MODIFIER_NAME)) is not None
            and m.node_group is not None]


def set_up(scene, colour_mode: str) -> list[str]:
    """Apply the splat render settings to `scene` and its splat objects (and a result's background sphere); the
    lines that changed."""
    from . import background_sphere

    lines = render_setup.apply(scene, colour_mode, objects=splat_objects(scene))
    for obj in [o for o in scene.objects if "gsgs_background_sphere" in o]:
        lines += background_sphere.set_colour_mode(obj, colour_mode)
    return lines


def report_changes(op, lines: list[str]) -> None:
    """One Info line per change (the Info editor keeps them), or one saying nothing changed."""
    if not lines:
        op.report({"INFO"}, "render settings already suit splats: nothing changed")
        return
    for line in lines:
        op.report({"INFO"}, f"splat render set-up: {line}")


class GSGS_OT_setup_splat_render(bpy.types.Operator):
    bl_idname = "gsgs.setup_splat_render"
    bl_label = "Set Up Splat Rendering"
    bl_description = ("Set the scene's render settings so splats look like the engine's render: transparent "
                      f"bounces {render_setup.TRANSPARENT_BOUNCES} (minimum = maximum), 1 sample at pixel centres, "
                      "no denoising, Raw or Standard view transform. Every change is listed in the Info editor; "
                      "undo reverts it")
    bl_options = {"REGISTER", "UNDO"}

    colour_mode: bpy.props.EnumProperty(name="Colours", items=COLOUR_ITEMS, default=render_setup.DEFAULT_COLOUR_MODE)

    def execute(self, context):
        report_changes(self, set_up(context.scene, self.colour_mode))
        return {"FINISHED"}


CLASSES = (GSGS_OT_setup_splat_render,)
