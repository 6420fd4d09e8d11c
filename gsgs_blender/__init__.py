"""GS-GS for Blender: photos -> cameras -> pseudo paths -> Gaussian-splat training -> splats.

The add-on is the thin, responsive half: it writes job folders, starts the engine
(`python -m gsgs_engine run-job DIR`, a separate interpreter with torch) and imports the
results. It imports only bpy and the engine's numpy-only layer (gsgs_engine.io / .job / .cameras).
"""

from __future__ import annotations

bl_info = {  # legacy add-on metadata; Blender 4.2+ reads blender_manifest.toml instead
    "name": "GS-GS: Generative Sparse-view Gaussian Splatting",
    "author": "gsgs contributors",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "View3D > Sidebar > GS-GS",
    "description": "Reconstruct a Gaussian-splat scene from a handful of photos",
    "category": "3D View",
}

_registered: tuple = ()


def register() -> None:
    global _registered
    import bpy

    from . import operators, panels, preferences, pseudo_paths, timeline

    preferences.register()
    classes = operators.all_classes() + panels.CLASSES
    for cls in classes:
        bpy.utils.register_class(cls)
    _registered = classes
    pseudo_paths.register_drawing()
    timeline.register_handler()


def unregister() -> None:
    global _registered
    import bpy

    from . import engine_install, job_runner, preferences, pseudo_paths, timeline

    timeline.unregister_handler()
    job_runner.stop_timer()
    engine_install.shutdown()
    pseudo_paths.unregister_drawing()
    for cls in reversed(_registered):
        bpy.utils.unregister_class(cls)
    _registered = ()
    preferences.unregister()
