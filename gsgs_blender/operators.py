"""Every operator class of the add-on, for registration (the helpers they share are in ops_common)."""

from __future__ import annotations

from . import ops_engine, ops_paths, ops_photos, ops_result, ops_setup, ops_train, ops_video


def all_classes() -> tuple:
    return ops_photos.CLASSES + ops_paths.CLASSES + ops_train.CLASSES + ops_result.CLASSES + ops_setup.CLASSES + ops_engine.CLASSES + ops_video.CLASSES
