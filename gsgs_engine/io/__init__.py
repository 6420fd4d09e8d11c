"""Datasets, PLY and EXR files; standard library + numpy only, so Blender's Python can import it.

`load_scene(path, format="auto", ...)` is the entry point; names are imported on first use so
`import gsgs_engine.io.scene` (or .ply) stays cheap and never pulls in another loader.
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "load_scene": "gsgs_engine.io.loader",
    "detect_format": "gsgs_engine.io.loader",
    "select_train": "gsgs_engine.io.selection",
    "FORMATS": "gsgs_engine.io.loader",
    "Scene": "gsgs_engine.io.scene",
    "View": "gsgs_engine.io.scene",
    "GaussianPly": "gsgs_engine.io.ply",
    "read_gaussian_ply": "gsgs_engine.io.ply",
    "write_gaussian_ply": "gsgs_engine.io.ply",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'gsgs_engine.io' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
