"""Training views as the dense initialisations see them: scaled to a working size, and their nearest others."""

from __future__ import annotations

import numpy as np

from gsgs_engine.cameras import Camera


def working_view(view, max_side: int, alpha_threshold: float) -> tuple[Camera, np.ndarray, np.ndarray]:
    """(camera, RGB float32 (H, W, 3), foreground mask (H, W)) of a scene.View at most max_side pixels long;
    RGBA views: pixels below alpha_threshold are background."""
    import cv2

    cam = view.camera
    factor = min(1.0, max_side / max(cam.width, cam.height))
    small = cam.scaled(factor)
    rgba = view.load_rgba()
    rgb = view.image()
    size = (small.width, small.height)
    if (small.width, small.height) != (cam.width, cam.height):
        rgb = cv2.resize(rgb, size, interpolation=cv2.INTER_AREA)
    if rgba.shape[2] == 4:
        alpha = rgba[..., 3] if size == (cam.width, cam.height) else cv2.resize(rgba[..., 3], size, interpolation=cv2.INTER_AREA)
        mask = alpha >= alpha_threshold
    else:
        mask = np.ones((small.height, small.width), dtype=bool)
    return small, np.ascontiguousarray(rgb, dtype=np.float32), mask


def nearest_sources(index: int, cameras: list[Camera], k: int) -> list[int]:
    """The k other cameras ranked by viewing-direction similarity to camera `index`, then by centre distance."""
    ref = cameras[index]
    scored = sorted((-float(ref.R[2] @ c.R[2]), float(np.linalg.norm(ref.center - c.center)), j)
                    for j, c in enumerate(cameras) if j != index)
    return [j for _, _, j in scored[:k]]
