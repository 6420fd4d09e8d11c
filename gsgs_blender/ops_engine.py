"""Install Engine, Cancel, Uninstall Engine: the add-on preferences' buttons (engine_install does the work)."""

from __future__ import annotations

import bpy

from gsgs_engine import GsgsError

from . import engine_install, job_runner
from .ops_common import report_error, timeout_property
from .preferences import check_engine, default_engine_root, default_python, get_prefs


def _installed(folder: str):
    """on_finish of a successful install: point Engine Python at it, Check Engine, drop older engines."""
    def callback(run: engine_install.InstallRun) -> None:
        if run.state != "ok":
            return
        prefs = get_prefs()
        prefs.python_path = run.final["python"]
        prefs.engine_root = ""  # the engine is installed in that Python; a checkout first on the path would shadow it
        ok, report = check_engine(prefs.python_path, "")
        prefs.engine_report = report
        engine_install.remove_engines(folder, keep=run.env)
        if not ok:
            run.state, run.message = "error", f"{run.message}; but Check Engine says: {report.replace(chr(10), '; ')}"
    return callback


class GSGS_OT_install_engine(bpy.types.Operator):
    bl_idname = "gsgs.install_engine"
    bl_label = "Install Engine"
    bl_description = ("Make a Python environment for the engine in the add-on's user folder: torch (CPU build, or "
                      "CUDA with an NVIDIA GPU), pycolmap, OpenCV, OpenEXR, the engine and its compiled kernel, "
                      "downloaded with pip (about 1.3 GB on disk with the CPU build). Runs in the background; then "
                      "Engine Python points at it and Check Engine runs. A failure or Cancel changes nothing")

    folder: bpy.props.StringProperty(
        name="Folder", default="", subtype="DIR_PATH", options={"SKIP_SAVE", "HIDDEN"},
        description="Where the engines folder goes (empty: the extension's user folder)")
    timeout: timeout_property()

    def execute(self, context):
        prefs = get_prefs(context)
        interactive = job_runner.ui_available()
        try:
            run = engine_install.start(prefs, folder=self.folder, on_finish=_installed(self.folder),
                                       use_timer=interactive)
        except GsgsError as exc:
            return report_error(self, exc)
        if interactive:
            self.report({"INFO"}, "Install Engine runs in the background: progress and Cancel in the GS-GS "
                                  "add-on preferences")
            return {"FINISHED"}
        run.wait(timeout=self.timeout or None)
        engine_install.finish(run)
        if run.state != "ok":
            self.report({"ERROR"}, run.message)
            return {"CANCELLED"}
        for warning in run.final.get("warnings", []):
            self.report({"WARNING"}, warning)
        self.report({"INFO"}, run.message)
        return {"FINISHED"}


class GSGS_OT_cancel_engine_install(bpy.types.Operator):
    bl_idname = "gsgs.cancel_engine_install"
    bl_label = "Cancel Install"
    bl_description = "Stop Install Engine; its half-made environment is deleted and Engine Python stays as it was"

    def execute(self, context):
        run = engine_install.current()
        if run is None or run.finished:
            self.report({"WARNING"}, "no Install Engine is running")
            return {"CANCELLED"}
        run.cancel()
        return {"FINISHED"}


class GSGS_OT_uninstall_engine(bpy.types.Operator):
    bl_idname = "gsgs.uninstall_engine"
    bl_label = "Uninstall Engine"
    bl_description = ("Delete the engine environments Install Engine made; Engine Python goes back to its default "
                      "when it pointed at one")

    folder: bpy.props.StringProperty(name="Folder", default="", subtype="DIR_PATH", options={"SKIP_SAVE", "HIDDEN"})

    def execute(self, context):
        run = engine_install.current()
        if run is not None and not run.finished:
            self.report({"ERROR"}, "Install Engine is running; cancel it first")
            return {"CANCELLED"}
        prefs = get_prefs(context)
        reset = engine_install.is_ours(bpy.path.abspath(prefs.python_path), self.folder)
        if reset:
            prefs.python_path, prefs.engine_root = default_python(), default_engine_root()
            prefs.engine_report = ""
        gone = engine_install.remove_engines(self.folder)
        self.report({"INFO"}, f"removed {len(gone)} engine environment(s)"
                              + (f"; Engine Python is {prefs.python_path} again" if reset else ""))
        return {"FINISHED"}


CLASSES = (GSGS_OT_install_engine, GSGS_OT_cancel_engine_install, GSGS_OT_uninstall_engine)
