"""A training time estimate the Train panel states before a job starts.

Scaled from `gsgs bench sparse` protocol cells run on the project's 2-core CPU machine (seed 0, 1000 steps),
one reference per recipe the engine can run, because they differ more than any single factor allows:
  - plain 3DGS: LLFF flower, 3 views at 504x378, 271 s (157,697 Gaussians: without the count control
    real photos grow them unchecked; 2026-11-25, not re-measured since the kernel's faster step of 2026-11-26,
    so it errs long);
  - `--prior auto` where the cameras look at a common point (an object orbit: MVS init, count control,
    dropout, the binocular shift every second step, no pseudo views): NeRF-synthetic lego, 8 views at 400x400,
    161 s (2026-11-26, right after the pinned f6f2ab9's cell, 222 s, on an otherwise idle machine);
  - `--prior auto` on a forward-facing rig (density-guided dropout, the binocular shift every step, warp-inpaint
    pseudo views at half size): LLFF flower at 504x378, 347 s (the same afternoon, after f6f2ab9's 531 s).
  The machine's day moves these by tens of percent (the same f6f2ab9 flower cell took 382 s one morning and 531 s
  that afternoon); the references of 2026-11-26 are the same afternoon's, back to back.
Which recipe auto runs is read from the training cameras as the engine's effect plan reads it: the
optical axes meet at a point (gsgs_engine.cameras.focus_point) -> the orbit recipe, else forward-facing.
Per step the time grows less than linearly with a view's pixels: seconds per step ~ pixels^0.71 (measured
between 200x200 and 1600x871 px runs of an earlier kernel, issue 15's photo job).
Checked (not fitted) on the default headless workflow, scripts/reconstruct.py on photos_santorini (3
photos, balanced preset: 1000 steps of auto at 640x340, an orbit by the cameras), 2026-11-26 right after the
reference cells, nothing else running: the orbit reference gives 200 s (the panel said "~3 min"); the training job
took 215 s, the whole workflow 246 s (2026-11-25, before the faster kernel step and the orbit recipe's
binocular view every second step: stated 250 s, trained 262 s, 289 s in all). It is a rough figure
(scene content, Gaussian counts and the machine's day move it by tens of percent) and the panel says so.
"""

from __future__ import annotations

from gsgs_engine import GsgsError

REFERENCE_ITERS = 1000
# recipe -> (seconds for REFERENCE_ITERS steps, pixels of a training view) measured as above
REFERENCES = {
    "plain": (271.0, 504 * 378),
    "orbit": (161.0, 400 * 400),
    "forward": (347.0, 504 * 378),
}
MIN_PIXEL_FACTOR = 0.05  # below ~100x100 px per-step overheads dominate
PIXEL_EXPONENT = 0.71


def train_size(width: int, height: int, resolution_scale: float, max_side: int = 0) -> tuple[int, int]:
    """The size views of width x height train at: scaled by resolution_scale, then the longer side capped
    at max_side (0: no cap), as gsgs_engine.io.loader.load_scene does."""
    scale = resolution_scale
    longest = max(width, height) * scale
    if max_side and longest > max_side:
        scale *= max_side / longest
    return round(width * scale), round(height * scale)


def recipe(generator: str, cameras=None) -> str:
    """Which measured recipe a run will be: "plain", "orbit" or "forward" (see REFERENCES).

    The generative priors (warp, diffusion) always render pseudo views; auto does where the cameras
    do not look at a common point, as the effect plan decides (cameras: gsgs_engine Camera objects)."""
    if generator in ("none", "depth"):
        return "plain"
    if generator != "auto":
        return "forward"
    if cameras is not None and len(cameras) >= 2:
        from gsgs_engine.cameras import focus_point

        if focus_point(cameras)[1] == "optical axes intersection":
            return "orbit"
    return "forward"


def estimate_seconds(iterations: int, width: int, height: int, resolution_scale: float, generator: str,
                     max_side: int = 0, cameras=None) -> float:
    """Rough CPU seconds of a training run of `iterations` steps on views of width x height."""
    seconds, ref_pixels = REFERENCES[recipe(generator, cameras)]
    w, h = train_size(width, height, resolution_scale, max_side)
    pixels = max(1.0, w * h)
    per_step = seconds / REFERENCE_ITERS * max(pixels / ref_pixels, MIN_PIXEL_FACTOR) ** PIXEL_EXPONENT
    return iterations * per_step


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
    try:
        cameras = [camera_convert.camera_from_object(o, scene) for o in objs]
    except GsgsError:  # a camera the engine cannot take: the job will say so; estimate as forward-facing
        cameras = None
    seconds = estimate_seconds(s.iterations, width, height, s.resolution_scale, s.generator, s.max_side, cameras)
    w, h = train_size(width, height, s.resolution_scale, s.max_side)
    kind = {"plain": "plain 3DGS", "orbit": "the orbit recipe", "forward": "the forward-facing recipe"}[
        recipe(s.generator, cameras)]
    return (f"~{format_duration(seconds)} on a 2-core CPU ({s.iterations} steps of {kind} on {w}x{h} px; a GPU is "
            "far faster)")
