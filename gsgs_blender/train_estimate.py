"""A training time estimate the Train panel states before a job starts.

Scaled from measured runs on the project's 2-core CPU machine: 1000 iterations at 200x200 px took
130 s without a prior (gsgs_engine/presets.py docstring, docs/accuracy_lego_200.md), the weights-free
prior costs 1.6x (llff_flower, same source), and a photo job at 1600x871 px with the prior took
257 s for 100 steps (issue 15's headless run). One step renders one training view, so the time
grows with the iterations and, less than linearly, with the pixels of a view: those two points give
seconds per step ~ pixels^0.7. It is a rough figure (Gaussian counts, densification and the machine
change it) and the panel says so.
"""

from __future__ import annotations

REFERENCE_SECONDS = 130.0  # 1000 it, 200x200 px, 2-core CPU, prior none (presets.py)
REFERENCE_ITERS = 1000
REFERENCE_PIXELS = 200 * 200
PRIOR_FACTOR = 1.6  # the weights-free prior on llff_flower (presets.py)
MIN_PIXEL_FACTOR = 0.25  # below ~100x100 px per-step overheads dominate
# 257 s / 100 steps / 1.6 (prior) = 1.6 s per step at 1600x871 against 0.13 s at 200x200:
# log(1.6 / 0.13) / log(1600 * 871 / 40000) = 0.71
PIXEL_EXPONENT = 0.71


def estimate_seconds(iterations: int, width: int, height: int, resolution_scale: float, generator: str) -> float:
    """Rough CPU seconds of a training run of `iterations` steps on views of width x height."""
    pixels = max(1.0, width * height * resolution_scale * resolution_scale)
    per_step = REFERENCE_SECONDS / REFERENCE_ITERS * max(pixels / REFERENCE_PIXELS, MIN_PIXEL_FACTOR) ** PIXEL_EXPONENT
    factor = PRIOR_FACTOR if generator not in ("none", "depth") else 1.0
    return iterations * per_step * factor


def format_duration(seconds: float) -> str:
    if seconds < 1:
        return "under 1 s"
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def estimate_text(scene) -> str:
    """'~N min on a 2-core CPU ...' for the scene's training cameras and Train fields ('' without cameras)."""
    from . import camera_convert, pseudo_paths

    objs = pseudo_paths.training_camera_objects(scene)
    if not objs:
        return ""
    sizes = [camera_convert.frame_of(o, scene)[:2] for o in objs]
    width = max(w for w, _ in sizes)
    height = max(h for _, h in sizes)
    s = scene.gsgs
    seconds = estimate_seconds(s.iterations, width, height, s.resolution_scale, s.generator)
    return (f"~{format_duration(seconds)} on a 2-core CPU ({s.iterations} steps on "
            f"{round(width * s.resolution_scale)}x{round(height * s.resolution_scale)} px; a GPU is far faster)")
