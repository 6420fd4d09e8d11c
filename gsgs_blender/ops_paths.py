"""Pseudo camera path operators: a curve through the training cameras, sampled into pseudo poses."""

from __future__ import annotations

import bpy
import numpy as np

from gsgs_engine import GsgsError

from . import pseudo_paths
from .ops_common import report_error


class GSGS_OT_make_pseudo_path(bpy.types.Operator):
    bl_idname = "gsgs.make_pseudo_path"
    bl_label = "Path Through Cameras"
    bl_description = ("Create an editable curve through the selected cameras' positions (all training cameras "
                      "when none is selected), ordered around their centre")
    bl_options = {"REGISTER", "UNDO"}

    closed: bpy.props.BoolProperty(name="Closed", default=True, description="Loop back to the first camera")
    kind: bpy.props.EnumProperty(name="Type", default="BEZIER", items=[
        ("BEZIER", "Smooth", "Bezier curve with automatic handles, passing through every camera"),
        ("POLY", "Straight", "straight segments between cameras")])

    @classmethod
    def poll(cls, context):
        cams = [o for o in context.selected_objects if o.type == "CAMERA"] or \
            pseudo_paths.training_camera_objects(context.scene)
        if len(cams) < 2:
            cls.poll_message_set("Select at least two cameras (or import photos first)")
            return False
        return True

    def execute(self, context):
        cams = [o for o in context.selected_objects if o.type == "CAMERA"] or \
            pseudo_paths.training_camera_objects(context.scene)
        positions = np.array([np.asarray(o.matrix_world)[:3, 3] for o in cams])
        order = pseudo_paths.ring_order(positions)
        try:
            obj = pseudo_paths.make_path_curve(context.scene, positions[order], closed=self.closed, kind=self.kind)
        except GsgsError as exc:
            return report_error(self, exc)
        self.report({"INFO"}, f"path {obj.name!r} through {len(cams)} cameras; edit it, then sample poses")
        return {"FINISHED"}


class GSGS_OT_sample_pseudo_poses(bpy.types.Operator):
    bl_idname = "gsgs.sample_pseudo_poses"
    bl_label = "Sample Pseudo Poses"
    bl_description = "Place the pseudo cameras evenly along the path (stored in the scene, sent with the training job)"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        settings = context.scene.gsgs
        if settings.pseudo_curve is None:
            cls.poll_message_set("Create or pick a path curve first")
            return False
        if not pseudo_paths.training_camera_objects(context.scene):
            cls.poll_message_set("No training cameras yet")
            return False
        return True

    def execute(self, context):
        try:
            cams = pseudo_paths.sample_pseudo_poses(context)
        except GsgsError as exc:
            return report_error(self, exc)
        _redraw(context)
        self.report({"INFO"}, f"{len(cams)} pseudo poses")
        return {"FINISHED"}


class GSGS_OT_clear_pseudo_poses(bpy.types.Operator):
    bl_idname = "gsgs.clear_pseudo_poses"
    bl_label = "Clear"
    bl_description = "Forget the sampled pseudo poses (training then uses only the automatic ones)"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not pseudo_paths.poses_from_json(context.scene.gsgs.pseudo_poses):
            cls.poll_message_set("No pseudo poses sampled")
            return False
        return True

    def execute(self, context):
        context.scene.gsgs.pseudo_poses = "[]"
        pseudo_paths.invalidate_draw_cache()
        _redraw(context)
        return {"FINISHED"}


def _redraw(context) -> None:
    screen = getattr(context, "screen", None)
    for area in getattr(screen, "areas", []):
        if area.type == "VIEW_3D":
            area.tag_redraw()


CLASSES = (GSGS_OT_make_pseudo_path, GSGS_OT_sample_pseudo_poses, GSGS_OT_clear_pseudo_poses)
