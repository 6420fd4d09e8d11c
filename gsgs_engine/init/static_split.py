"""Which initial points of a multi-view video are the still background and which move.

A synchronised rig films a mostly still scene (a room, a dome) with a few moving subjects. A 4D model
initialised per frame holds the still background once per frame, each copy visible for a few frames
only, so every copy learns from a fraction of the clip. Points that project, in every training view
of their frame, onto pixels that keep their colour over the clip (within `threshold` of the camera's
temporal median) are the background: they can start as one time-constant set that every frame
supervises. The rest follow their frame.

Entry: `moving_point_mask(points, views, medians)`, with `camera_medians(frames)` giving each camera's
temporal median image.
"""

from __future__ import annotations

import numpy as np

# A pixel moves where a channel leaves its camera's temporal median by more than this (colours in [0, 1]);
# the same rule the dynamic-region score of `gsgs bench dynamic` uses to find what changes.
MOVING_THRESHOLD = 0.1


def camera_key(view) -> object:
    """The physical camera of a video frame's view (its loader's camera index, else its pose)."""
    extra = view.camera.extra or {}
    if "camera_index" in extra:
        return ("camera", int(extra["camera_index"]))
    return ("pose", tuple(np.round(np.asarray(view.camera.center, dtype=np.float64), 6)))


def camera_medians(frames: dict) -> dict:
    """{camera key: (H, W, 3) temporal median image} over the frames each camera filmed (frames: time -> views)."""
    stacks: dict = {}
    for views in frames.values():
        for view in views:
            stacks.setdefault(camera_key(view), []).append(np.asarray(view.image(), dtype=np.float32)[..., :3])
    return {key: np.median(np.stack(images), axis=0) for key, images in stacks.items() if len(images) >= 2}


def moving_pixels(image: np.ndarray, median: np.ndarray, threshold: float = MOVING_THRESHOLD) -> np.ndarray:
    """(H, W) bool: the pixels of one frame that differ from the camera's median by more than threshold."""
    diff = np.abs(np.asarray(image, dtype=np.float32)[..., :3] - median)
    return np.nan_to_num(diff, nan=1.0).max(axis=-1) > threshold


def moving_point_mask(points: np.ndarray, views: list, medians: dict,
                      threshold: float = MOVING_THRESHOLD) -> np.ndarray:
    """(N,) bool: True for points that land on a moving pixel in at least one of the frame's views that sees
    them (in front of the camera, inside the image). A point no view with a median sees counts as moving:
    nothing shows it is still. Occlusion is not modelled, so a background point hidden behind a moving subject
    in one view stays with its frame (the safe side)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    moving = np.zeros(len(points), dtype=bool)
    seen = np.zeros(len(points), dtype=bool)
    for view in views:
        median = medians.get(camera_key(view))
        if median is None:
            continue
        cam = view.camera
        uv, z = cam.project(points)
        px = np.floor(uv[:, 0])
        py = np.floor(uv[:, 1])
        inside = np.isfinite(z) & (z > 1e-9) & (px >= 0) & (px < cam.width) & (py >= 0) & (py < cam.height)
        mask = moving_pixels(view.image(), median, threshold)
        if mask.shape != (cam.height, cam.width):
            raise ValueError(f"view {view.name!r}: image {mask.shape} does not match its camera "
                             f"({cam.height}, {cam.width})")
        idx = np.flatnonzero(inside)
        moving[idx] |= mask[py[idx].astype(np.int64), px[idx].astype(np.int64)]
        seen |= inside
    return moving | ~seen
