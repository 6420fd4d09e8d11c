"""A training time estimate the Train panel states before a job starts.

Scaled from the engine's measured runs (gsgs_engine/presets.py docstring, docs/accuracy_lego_200.md):
on a 2-core CPU, 1000 iterations at 200x200 px took 130 s without a prior, and the weights-free
prior cost 1.6x (llff_flower). One step renders one training view, so the time grows with the
iterations and with the pixels of a view. It is a rough figure (Gaussian counts, densification and
the machine change it) and says so.
"""

from __future__ import annotations

REFERENCE_SECONDS = 130.0  # 1000 it, 200x200 px, 2-core CPU, prior none (presets.py)
REFERENCE_ITERS = 1000
REFERENCE_PIXELS = 200 * 200
PRIOR_FACTOR = 1.6  # the weights-free prior on llff_flower (presets.py)
MIN_PIXEL_FACTOR = 0.25  # below ~100x100 px per-step overheads dominate


def estimate_seconds(iterations: int, width: int, height: int, resolution_scale: float, generator: str) -> float:
    """Rough CPU seconds of a training run of `iterations` steps on views of width x height."""
    pixels = max(1.0, width * height * resolution_scale * resolution_scale)
    per_step = REFERENCE_SECONDS / REFERENCE_ITERS * max(pixels / REFERENCE_PIXELS, MIN_PIXEL_FACTOR)
    factor = PRIOR_FACTOR if generator not in ("none", "depth") else 1.0
    return iterations * per_step * factor


def format_duration(seconds: float) -> str:
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
