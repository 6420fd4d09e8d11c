"""The dynamic region of a multi-view video's test views: where a frozen model cannot score.

A model that learns the static dome and freezes (or drops) the people still scores well on whole
images, because the dome fills most of them. `gsgs bench dynamic` therefore also reports PSNR
inside the region that moves:
  - the capture's foreground masks where it has them (Panoptic's seg/, io.panoptic.load_mask);
  - else the pixels that change over time: per camera, those whose colour differs from the camera's
    per-pixel median over the frames by more than CHANGE_THRESHOLD in some channel.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

CHANGE_THRESHOLD = 0.1  # colour difference from the camera's median frame (images in [0, 1])
MIN_FRAMES_FOR_CHANGE = 3  # a median of fewer frames does not tell background from motion


def changing_pixels(images: list[np.ndarray], threshold: float = CHANGE_THRESHOLD) -> list[np.ndarray]:
    """Per image (H x W x 3 of one camera at successive frames): bool H x W of the pixels that differ
    from the per-pixel median over all the images by more than `threshold` in some channel."""
    if len(images) < MIN_FRAMES_FOR_CHANGE:
        raise ValueError(f"changing_pixels needs at least {MIN_FRAMES_FOR_CHANGE} frames of a camera "
                         f"(got {len(images)})")
    stack = np.stack([np.asarray(im, dtype=np.float32)[..., :3] for im in images])
    median = np.median(stack, axis=0)
    return list(np.abs(stack - median[None]).max(axis=-1) > threshold)


def region_masks(views) -> tuple[Callable, str]:
    """(view -> bool mask or None, a description) for the test views of a multi-view video.

    Foreground masks when every view has one (Camera.extra["mask_path"]); otherwise the changing
    pixels of each camera's frames, computed once here (cameras with fewer than three frames get None).
    """
    from gsgs_engine.io.panoptic import load_mask

    if views and all(v.camera.extra.get("mask_path") for v in views):
        return load_mask, "the capture's foreground masks (seg/)"
    by_camera: dict = {}
    for v in views:
        by_camera.setdefault(v.camera.extra.get("camera_index", v.camera.name), []).append(v)
    masks: dict[int, np.ndarray] = {}
    for cam_views in by_camera.values():
        if len(cam_views) < MIN_FRAMES_FOR_CHANGE:
            continue
        for v, m in zip(cam_views, changing_pixels([v.image() for v in cam_views])):
            masks[id(v)] = m
    return (lambda view: masks.get(id(view))), (f"pixels that change over time (> {CHANGE_THRESHOLD} from the "
                                                "camera's median frame)")


__all__ = ["CHANGE_THRESHOLD", "changing_pixels", "region_masks"]
