"""The effect plan: inspect a scene before training and model only the effects it calls for.

Each effect is decided from the data (or set by the user) with its measurement and reason:
the rig (forward-facing, object orbit or inward shell, and the near plane it needs), time (4D),
view-dependent colour (SH degree), background (alpha learned on RGBA views; the photos' mean colour behind
RGB photos under the weights-free recipe), depth regularisation, pseudo views,
the generator, the weights-free techniques, the initialisation and the position learning rate (a multiple of
3DGS's, raised by the recipe on object orbits and videos). A disabled effect is never set up, so it costs nothing.
The plan is printed, saved as metrics.json["plan"]["effects"], and overridable
(`--effects sh_degree=0,pseudo_views=off`).
"""

from __future__ import annotations

import contextlib
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError
from gsgs_engine.cameras import focus_point

EFFECTS = ("rig", "time", "sh_degree", "background", "depth", "pseudo_views", "generator", "techniques", "init",
           "position_lr", "attribute_lr")

# -- documented thresholds ---------------------------------------------------------------------
# Pseudo views: sparse-view benchmarks train on 3-9 views (LLFF 3, DTU 3, NeRF-synthetic 8);
# dense captures have tens to hundreds. Below DENSE_MIN_VIEWS views a scene is sparse whatever
# the layout. Above it, a scene is still sparse where its views leave angular holes: the
# median angle, seen from the scene's focus, between a view and its nearest neighbour exceeds
# DENSE_MAX_GAP_DEG (measured: lego_200's 75 train+dense views 8.4 deg, its 8 sparse views
# 24.6 deg; llff_flower's 29 train views 0.9 deg, 3 of them 1.9 deg).
DENSE_MIN_VIEWS = 12
DENSE_MAX_GAP_DEG = 20.0
# View-dependent colour: the median, over SfM points seen in >= 2 training views, of the RMS
# spread of a point's colour across those views after removing a per-view, per-channel gain
# (exposure / white balance) and, in quadrature, the spread its localisation error explains
# on the local texture. The median speaks for the typical surface, not a few highlights.
# Below SH_SPREAD[0] (5/255) a scene reads as diffuse; above SH_SPREAD[k-1] it asks for
# degree >= k. Measured: lego_200 8 views 0.000 (p90 0.045), llff_flower 3 views 0.012
# (p90 0.048): both diffuse for their typical surface.
SH_SPREAD = (0.02, 0.04, 0.07)
# ... except under `--prior auto` on an object orbit, where degree AUTO_ORBIT_SH_DEGREE (2) is given when a tenth of the
# points (the p90 of the same spread) vary by SH_SPREAD[0] or more, past the views' identifiability cap: the recipe's
# regularisers (dropout, opacity decay, the binocular view) keep the extra coefficients from fitting noise, and some
# surfaces shine. NeRF-synthetic 8 views (cap: degree 1), 1000 steps, CPU, seeds 0-2, --prior auto:
#   degree 0 -> 1 (session 20): 26.52 +- 0.10 -> 26.73 +- 0.11 dB (every seed +0.17 to +0.27 on the mean);
#   degree 1 -> 2 (session 21, after the kernel's new rounding): 26.66 +- 0.05 -> 26.88 +- 0.09 dB (lego p90 0.041:
#   24.98 / 24.92 / 25.17 -> 25.02 / 25.22 / 25.16, chair p90 0.057: 28.45 / 28.35 / 28.09 -> 28.56 / 28.69 / 28.62;
#   every seed +0.08 to +0.32 on the mean, SSIM 0.917 -> 0.919, LPIPS 0.086 -> 0.085) at ~1.08x the training time;
#   degree 3 (session 22, seed 0): lego 24.97 (degree 2: 25.02), no better.
# Other rigs and plain 3DGS keep the median's degree under the cap (not measured past it); forward-facing captures of
# 3 views identify degree 0 anyway. Only 8-view orbits were measured past the cap: 4-7 views (cap 1) get degree 2 too,
# 3 views (cap 0: the 3-photo workflow) stay at degree 0.
AUTO_ORBIT_SH_QUANTILE_KEY = "spread_p90"
AUTO_ORBIT_SH_DEGREE = 2
AUTO_ORBIT_SH_MEASURED = ("NeRF-synthetic 8 views, seeds 0-2, --prior auto on an orbit: degree 0 -> 1 26.52 -> 26.73 "
                          "dB (session 20), degree 1 -> 2 26.66 -> 26.88 dB (session 21; docs/sparse_techniques.md)")
MIN_MEASURED_POINTS = 20
# Depth regularisation from SfM points needs enough of them to cover the views (as the prior's
# own plan: gsgs_engine.priors.config.resolve_prior_plan).
MIN_DEPTH_POINTS = 50
# Weights-free sparse-view techniques (gsgs_engine.train.techniques) that `--prior auto` turns on for
# sparse static scenes: the combination measured best (docs/sparse_techniques.md, 1000 steps, CPU,
# one seed): llff_flower 3 views at half resolution 16.84 -> 18.27 dB in a third of the time
# (the budget keeps 14k Gaussians instead of 144k), lego_200 8 views 22.83 -> 23.16 dB at 2.1x.
AUTO_TECHNIQUES = ("count_control", "dropout", "binocular", "opacity_decay")
# On a forward-facing rig the dropout is density-guided (D2GS: crowded Gaussians dropped more often, the same
# mean rate, unbiased; techniques/dropout.py). LLFF protocol, 3 views, 1000 steps, CPU, seeds 0-2: 20.39 +- 0.14
# -> 20.65 +- 0.10 dB (flower 20.77 -> 21.00, horns 20.01 -> 20.29), LPIPS and SSIM equal or better. On the
# NeRF-synthetic orbits seed 0 moved lego +0.09 and chair -0.16 dB, so the orbit recipe keeps uniform dropout.
# Against no dropout at all (session 40, today's recipe otherwise): LLFF seeds 0-2 20.67 -> 20.75 dB (flower -0.03,
# horns +0.17), though LPIPS is 0.011 better without it; so it stays (docs/sparse_techniques.md, "Session 40").
# The binocular shifted view renders at half size there (a quarter of its pixels; its warp compares the
# area-averaged photo): LLFF, 3 views, 1000 steps, CPU, seeds 0-2, this recipe with the view at full size against
# half (2026-11-27): 20.49 -> 20.52 dB (flower 20.83 -> 20.78, horns 20.15 -> 20.25; paired by seed -0.06 / +0.07 /
# +0.07; SSIM 0.694 -> 0.693, LPIPS 0.313 -> 0.316), the cell's total seconds about 0.87x (docs/speed.md). On the
# orbits the half-size view lost 0.10 dB (CUDA grid of 2026-11-26), so they keep the full-size one every 2nd step.
# Below 3000 steps it densifies by AbsGS's absolute gradients (techniques/absgrad.py, threshold 4 x 3DGS's; session
# 29): LLFF 3 views, 1000 steps, CPU, seeds 0-2, 20.63 -> 20.70 dB, SSIM 0.696 -> 0.701, LPIPS (VGG) 0.315 -> 0.307,
# the same Gaussian count (the budget binds there). At 3000 steps it buys more (sessions 41-42, below), so the
# long forward recipe has it too.
AUTO_FORWARD_TECHNIQUES = ("absgrad", "count_control", "dropout:guide=density", "binocular:scale=0.5", "opacity_decay")
AUTO_FORWARD_MEASURED = ("density-guided dropout on a forward-facing rig: LLFF 3 views, seeds 0-2, 20.39 -> 20.65 dB "
                         "(docs/sparse_techniques.md); the binocular view at half size there: 20.49 -> 20.52 dB at "
                         "about 0.87x the time (docs/speed.md); densified by absolute gradients (AbsGS): 20.63 -> "
                         "20.70 dB, LPIPS 0.315 -> 0.307 (docs/sparse_techniques.md)")
# On an object orbit the binocular shifted view is rendered every second step from its start (with the depth
# distortion's half-size composite every 8th step, below, the recipe's extra renders there). NeRF-synthetic 8 views,
# 1000 steps, CPU, seeds 0-2: 26.17 +- 0.05 -> 26.12 +- 0.07 dB (lego 24.46 -> 24.42, chair 27.87 -> 27.82; SSIM
# and LPIPS equal to the third decimal), lego trained 1.28x faster (201 -> 157 s, back to back on a quiet machine;
# docs/speed.md). Inward shells keep the shifted view every step (not measured there).
# The orbit's dropout ends at rate 0.1, not DropGaussian's 0.2 (session 23): NeRF-synthetic 8 views, 1000 steps,
# CPU, seeds 0-2, 26.84 +- 0.09 -> 26.97 +- 0.04 dB (lego 24.84 / 24.92 / 25.13 -> 25.20 / 25.14 / 25.14, chair
# 28.81 / 28.59 / 28.73 -> 28.74 / 28.87 / 28.72; SSIM and LPIPS better); fewer Gaussians dropped leave a training
# render a little more to draw. Seed 0: 0.05 26.73, 0.2 26.83, 0.3 26.85, none 26.94. Long schedules keep 0.2 (0.1 at
# 3000 steps, seed 0: 27.42 against 27.52); forward-facing rigs keep their density-guided 0.2.
# Densification there clones Gaussians up to 0.005 of the scene extent and splits larger ones (3DGS: 0.01;
# techniques/clone_split.py; session 38): NeRF-synthetic 8 views, 1000 steps, CPU, seeds 0-2, 26.87 -> 26.98 dB (lego
# 24.99 / 25.07 / 25.12 -> 25.30 / 25.16 / 25.18, chair 28.86 / 28.55 / 28.63 -> 28.72 / 28.68 / 28.86; paired by seed
# +0.09 / +0.11 / +0.15; SSIM 0.919 -> 0.922, LPIPS 0.083 -> 0.079), the same seconds, 3 % more Gaussians; seed 0
# at 0.0025: 26.74, at 0.02: 26.84. Long schedules clone and split at the same boundary (session 39, below).
# It charges each training ray for the spread of its depth (techniques/distortion.py, depth distortion: weight 6 every
# 8th step from 0.2 of the run; session 47): NeRF-synthetic 8 views, 1000 steps, CPU, seeds 0-2, 27.26 +- 0.09 ->
# 27.40 +- 0.16 dB (lego 25.39 / 25.17 / 25.25 -> 25.63 / 25.24 / 25.35, chair 29.32 / 29.16 / 29.24 -> 29.52 / 29.26
# / 29.39; every cell higher; SSIM 0.925 -> 0.926, LPIPS 0.073 -> 0.072). Weight 1 at every step gained as much
# (27.40) at ~1.45x a step, weight 3 every 4th step 27.39 at 1.16x; every 8th costs ORBIT_DISTORTION_FACTOR
# (gsgs_blender/train_estimate.py). On a forward-facing rig it loses (LLFF flower seed 0, weight 1 at every step:
# 21.02 -> 20.70; session 46); long schedules, inward shells and videos were not measured with it.
AUTO_ORBIT_TECHNIQUES = ("clone_split", "count_control", "dropout:max_rate=0.1", "binocular:every=2", "opacity_decay",
                         "distortion")
AUTO_ORBIT_MEASURED = ("the binocular view every second step on an object orbit: NeRF-synthetic 8 views, seeds 0-2, "
                       "26.17 -> 26.12 dB at 1.28x the speed (docs/speed.md); dropout to rate 0.1 there: 26.84 -> "
                       "26.97 dB (docs/sparse_techniques.md); the clone / split boundary at 0.005 of the scene extent: "
                       "26.87 -> 26.98 dB (docs/sparse_techniques.md); depth distortion every 8th step: 27.26 -> "
                       "27.40 dB (docs/sparse_techniques.md)")
# With a long schedule (the `best` preset's 3000 steps or more) the orbit recipe renders the shifted view at every
# step again: there the time matters less and the view buys more. NeRF-synthetic 8 views, 3000 steps, CPU, seeds 0-2:
# 26.99 +- 0.07 -> 27.16 +- 0.11 dB (lego 25.40 -> 25.50, chair 28.58 -> 28.82; paired by seed +0.34 / +0.06 / +0.11;
# SSIM 0.924 -> 0.925, LPIPS 0.076 -> 0.075), at about 1.28x a step (docs/speed.md).
# The clone / split boundary at 0.005 of the scene extent holds there too (session 39): NeRF-synthetic 8 views,
# 3000 steps, CPU, seeds 0-2, 27.42 +- 0.06 -> 27.63 +- 0.10 dB (lego 25.60 / 25.57 / 25.68 -> 25.79 / 25.78 / 25.92,
# chair 29.09 / 29.31 / 29.27 -> 29.22 / 29.53 / 29.57; paired by seed +0.16 / +0.21 / +0.27; SSIM 0.928 -> 0.930, LPIPS
# 0.072 -> 0.068), the same seconds (184 -> 179 s of training a cell), 1 % more Gaussians; unseen seeds 3-5: 27.57 ->
# 27.61 (four of six cells higher, LPIPS lower on all six).
AUTO_LONG_STEPS = 3000
AUTO_ORBIT_LONG_TECHNIQUES = ("clone_split",) + AUTO_TECHNIQUES
AUTO_ORBIT_LONG_MEASURED = ("the binocular view at every step on an object orbit trained 3000 steps or more: "
                            "NeRF-synthetic 8 views at 3000 steps, seeds 0-2, 26.99 -> 27.16 dB (docs/speed.md); the "
                            "clone / split boundary at 0.005 of the scene extent there: 27.42 -> 27.63 dB at 3000 steps "
                            "(docs/sparse_techniques.md)")
# A forward-facing rig trained as long keeps the binocular view at full size: the half-size view was measured at
# 1000 steps only, and the LLFF figures at 3000 steps (20.86 +- 0.09 dB, the `best` preset) were made with the full one.
# It does not take the orbits' clone / split boundary: LLFF 3 views at 3000 steps, seeds 0-2, 20.81 -> 20.96 dB, but
# unseen seeds 3-5 20.96 -> 20.93 (sessions 40-41, docs/sparse_techniques.md; level at 1000 steps too, session 38).
# It densifies by AbsGS's absolute gradients, as the 1000-step recipe does (sessions 41-42): LLFF 3 views at 3000
# steps, CPU, seeds 0-2 20.81 -> 21.24 dB (every cell higher, +0.29 to +0.61), unseen seeds 3-5 20.96 -> 21.16
# (every cell higher, +0.10 to +0.28); seeds 0-5 20.88 -> 21.20 +- 0.06, SSIM 0.719 -> 0.726, LPIPS (VGG) 0.266 ->
# 0.257, the same Gaussian count, ~15 % more training seconds a cell (docs/sparse_techniques.md, "Session 42").
AUTO_FORWARD_LONG_TECHNIQUES = ("absgrad", "count_control", "dropout:guide=density", "binocular", "opacity_decay")
AUTO_FORWARD_LONG_MEASURED = ("density-guided dropout and the binocular view at full size on a forward-facing rig "
                              "trained 3000 steps or more: LLFF 3 views at 3000 steps, seeds 0-2, 20.86 dB "
                              "(docs/speed.md); densified by absolute gradients (AbsGS) there: 20.88 -> 21.20 dB over "
                              "seeds 0-5 (docs/sparse_techniques.md)")
# the recipe of each rig type for schedules of AUTO_LONG_STEPS or more, where it differs
AUTO_LONG_RIG_RECIPES = {"forward-facing": (AUTO_FORWARD_LONG_TECHNIQUES, AUTO_FORWARD_LONG_MEASURED),
                         "object orbit": (AUTO_ORBIT_LONG_TECHNIQUES, AUTO_ORBIT_LONG_MEASURED)}
# the recipe of each rig type; a rig not named here gets AUTO_TECHNIQUES
AUTO_RIG_RECIPES = {"forward-facing": (AUTO_FORWARD_TECHNIQUES, AUTO_FORWARD_MEASURED),
                    "object orbit": (AUTO_ORBIT_TECHNIQUES, AUTO_ORBIT_MEASURED)}
# ... and starts from the dense multi-view-stereo initialisation (gsgs_engine.init.mvs) where the
# user chose no init: with the techniques, lego_200 23.16 -> 25.36 dB, llff_flower (half res.)
# 18.27 -> 19.73 dB (same protocol as above).
# On a multi-view video (4D) --prior auto runs its own recipe: the dense MVS init once per frame and per-camera
# exposure (techniques/exposure.py). Measured on the Panoptic capture (9 of its cameras, 10 frames at 320x180,
# 1000 steps, one seed, test cameras with the shell's near plane; docs/dynamic_panoptic.md): 4D PSNR / dynamic
# region 19.08 / 17.08 dB from triangulated points, 18.94 / 17.35 with exposure, 18.60 / 19.07 with the MVS init,
# 20.16 / 19.98 with both; the static recipe's four techniques on top of the MVS init gave 18.41 / 16.96.
AUTO_4D_TECHNIQUES = ("exposure",)
AUTO_4D_MEASURED = ("measured on a 9-camera Panoptic clip (one seed): 4D 19.08 -> 20.16 dB, dynamic region 17.08 -> "
                    "19.98 dB; the static recipe's techniques measured worse on video (docs/dynamic_panoptic.md)")
# With few cameras a frame, dropout and opacity decay join them (catalogue order). Same capture and protocol, the
# 4D model alone: 3 cameras 17.18 -> 17.45 dB, 6 cameras 17.94 -> 18.85; at 9 cameras they cost 20.16 -> 17.67,
# so the line sits between the counts measured (one capture, one seed; its held-out time window checks it).
AUTO_4D_FEW_CAMERAS = 6
AUTO_4D_FEW_TECHNIQUES = ("dropout", "opacity_decay", "exposure")
AUTO_4D_FEW_MEASURED = ("with dropout and opacity decay at <= 6 cameras a frame, measured on the Panoptic clip (one "
                        "seed): 4D 17.18 -> 17.45 dB at 3 cameras, 17.94 -> 18.85 at 6; at 9 they cost 20.16 -> 17.67 "
                        "(docs/dynamic_panoptic.md)")

# The Gaussians' position learning rate. 3DGS's (1.6e-4 x the scene extent, decayed log-linearly to 1/100 of it)
# is made for 30,000 steps; over the recipe's 1000 a Gaussian can travel a thirtieth as far, and on object orbits
# and videos the recipe's models are under-moved: there `--prior auto` multiplies it by POSITION_LR_SCALE.
# Measured (1000 steps, CPU, seeds 0-2; docs/sparse_techniques.md and docs/dynamic_panoptic.md, "Session 14"):
# NeRF-synthetic 8 views 26.06 +- 0.03 -> 26.57 +- 0.12 dB (lego 24.37 -> 24.94, chair 27.75 -> 28.20, every
# seed; SSIM and LPIPS better; ~10 % more Gaussians); x2 / x6 on lego seed 0: 24.68 / 24.94 against 24.85 at x3.
# The Panoptic clip's 4D model (10 frames): 9 cameras 23.58 -> 24.06 dB, 6 cameras 20.64 -> 21.07, 3 cameras 17.57 ->
# 17.61 (the static baselines gain less: docs/dynamic_panoptic.md). On forward-facing LLFF it lost (flower 20.80 ->
# 20.69, horns 20.25 -> 20.12, seed 0), so that recipe keeps 3DGS's rate.
POSITION_LR_SCALE = 3.0
POSITION_LR_MEASURED = ("measured at 1000 steps over seeds 0-2: NeRF-synthetic 8 views 26.06 -> 26.57 dB, the "
                        "Panoptic 4D model with 9 / 6 cameras 23.58 -> 24.06 / 20.64 -> 21.07 dB; LLFF "
                        "(forward-facing) lost 0.1 dB, so it keeps 1 (docs/sparse_techniques.md)")

# A schedule of AUTO_LONG_STEPS or more already lets the means travel that much farther: at 3000 steps (the `best`
# preset's orbit recipe, seed 0) lego 25.52 dB with 3DGS's rate, 25.51 with x3; chair 29.00 -> 28.93. So long
# schedules keep 3DGS's.
POSITION_LR_LONG_MEASURED = ("x3 measured flat at 3000 steps on an object orbit: NeRF-synthetic seed 0, lego 25.52 -> "
                             "25.51, chair 29.00 -> 28.93 dB (docs/sparse_techniques.md)")


def _asked_rate(key: str, train_config) -> "Effect | None":
    """The user's multiple of a learning rate (`gsgs train --KEY-scale`, the job setting "KEY_scale") as the plan's
    `key` effect, or None where none was given."""
    asked = getattr(train_config, f"{key}_scale", None)
    if asked is None:
        return None
    flag = key.replace("_", "-") + "-scale"
    return Effect(key, float(asked) != 1.0, float(asked), f"--{flag} / job setting \"{key}_scale\"", "user")


def position_lr_effect(train_config, effects: dict, requested: str, sparse: bool) -> "Effect":
    """The plan's "position_lr": the user's multiple, else the recipe's on object orbits and videos, else 1."""
    asked = _asked_rate("position_lr", train_config)
    if asked is not None:
        return asked
    video = effects["time"].enabled
    if requested != "auto" or not (video or (sparse and effects["rig"].value == "object orbit")):
        return Effect("position_lr", False, 1.0, "3DGS's position learning rate, its schedule scaled to the run")
    if int(train_config.iters) >= AUTO_LONG_STEPS:
        return Effect("position_lr", False, 1.0, f"{int(train_config.iters)} steps (>= {AUTO_LONG_STEPS}): 3DGS's "
                      "position learning rate; " + POSITION_LR_LONG_MEASURED)
    where = "4D" if video else "sparse object orbit"
    return Effect("position_lr", True, POSITION_LR_SCALE, f"{where} under --prior auto: 3DGS's position learning "
                  f"rate x{POSITION_LR_SCALE:g}; " + POSITION_LR_MEASURED)


# The colour (SH), scale and rotation learning rates. With the positions at x3 the object-orbit recipe's Gaussians
# still reach their size slowly in 1000 steps: the scales' rate is what gains (session 15: colour and rotations x3
# alone gave nothing). Session 15 left it out because 20 % more steps bought the same then; on today's orbit recipe
# (1000 steps, CPU, seeds 0-2; docs/sparse_techniques.md, "Session 45") lego 25.08 -> 25.27 dB, chair 28.82 ->
# 29.24 (every seed higher, SSIM and LPIPS better too), and at 300 steps 23.97 -> 25.26. The forward-facing recipe
# gains too: LLFF flower 20.95 -> 21.02, horns 20.44 -> 20.67 (5 of 6 cells higher, SSIM and LPIPS better), for about
# 1.35x the training seconds (larger footprints composite longer). Inward shells, videos and long schedules keep
# 3DGS's rates (not measured with it).
ATTRIBUTE_LR_SCALE = 3.0
ATTRIBUTE_LR_RIGS = ("object orbit", "forward-facing")
ATTRIBUTE_LR_MEASURED = ("measured at 1000 steps over seeds 0-2: NeRF-synthetic 8 views 26.95 -> 27.26 dB (every "
                         "cell higher; SSIM 0.922 -> 0.925, LPIPS 0.079 -> 0.073), LLFF 3 views 20.69 -> 20.85 dB "
                         "(SSIM 0.700 -> 0.706, LPIPS 0.308 -> 0.294; about 1.35x the training seconds there); "
                         "docs/sparse_techniques.md")


def attribute_lr_effect(train_config, effects: dict, requested: str, sparse: bool) -> "Effect":
    """The plan's "attribute_lr": the user's multiple, else the recipe's on short sparse object orbits and
    forward-facing rigs, else 1."""
    asked = _asked_rate("attribute_lr", train_config)
    if asked is not None:
        return asked
    rig = effects["rig"].value
    measured = sparse and rig in ATTRIBUTE_LR_RIGS and not effects["time"].enabled
    if requested != "auto" or not measured or int(train_config.iters) >= AUTO_LONG_STEPS:
        return Effect("attribute_lr", False, 1.0, "3DGS's colour, scale and rotation learning rates")
    return Effect("attribute_lr", True, ATTRIBUTE_LR_SCALE, f"sparse {rig} rig under --prior auto below "
                  f"{AUTO_LONG_STEPS} steps: 3DGS's colour, scale and rotation learning rates x{ATTRIBUTE_LR_SCALE:g}; "
                  + ATTRIBUTE_LR_MEASURED)


def viewpoints(cameras) -> list:
    """One camera per distinct viewpoint (centre and rotation), first seen first: a multi-view video's
    training views are its cameras at every frame, but what a Gaussian's colour and the rig's coverage can learn
    from are the viewpoints. Static views come back as they are (no two share a pose)."""
    if len(cameras) < 2:
        return list(cameras)
    centres = np.stack([np.asarray(c.center, np.float64) for c in cameras])
    spread = float(np.linalg.norm(centres - centres.mean(0), axis=1).max())
    tol = max(spread, 1e-12) * 1e-6
    seen: list[tuple[np.ndarray, np.ndarray]] = []
    out = []
    for cam, centre in zip(cameras, centres):
        rot = np.asarray(cam.R, np.float64)
        if not any(np.linalg.norm(centre - c) <= tol and np.abs(rot - r).max() <= 1e-6 for c, r in seen):
            seen.append((centre, rot))
            out.append(cam)
    return out


def _viewpoint_count(views: int, distinct: int) -> str:
    return f"{views} views" if views == distinct else f"{distinct} viewpoints ({views} views)"


def cameras_per_frame(views) -> int:
    """How many training cameras film a moment of a video: the most views that share one time."""
    counts: dict = {}
    for v in views:
        counts[v.camera.time] = counts.get(v.camera.time, 0) + 1
    return max(counts.values(), default=0)
MVS_MEASURED = ("dense MVS init measured with the techniques: lego_200 23.16 -> 25.36 dB, llff_flower (half "
                "resolution) 18.27 -> 19.73 dB")
# The weights-free warp-inpaint generator under --prior auto: on forward-facing rigs only. Its ring of
# pseudo views and its filling target content beside the rig; on orbits its targets, warped across
# 25-33 deg camera gaps, are worse than the render (1000 steps, CPU, one seed; with the techniques on):
WARP_MEASURED = ("warp-inpaint measured with the techniques: llff_flower (forward-facing, 3 views, half "
                 "resolution) 18.27 -> 19.71 dB, lego_200 (orbit, 8 views) 23.16 -> 21.83 dB")
# The background. RGBA views (NeRF-synthetic): "transparent", a random colour each step that the target is
# re-composited on, so alpha is learned. RGB photos have no background of their own: every pixel shows the scene.
# With a fixed (white) background a sparse model can paint light surfaces with faint splats over it, and views
# between the photos show that background wherever their coverage differs. "opaque" (`--effects
# background=opaque`, `--random-background` on RGB views) puts a random colour behind each step's render and
# keeps the photo as the target, so whatever a photo shows must be covered by opaque splats. It is a setting,
# not an auto choice: measured (1000 steps, seed 0) it gained in one configuration and lost in the others --
# panoptic_basketball frame 0, 9 cameras, --init mvs --techniques exposure, half resolution: 15.01 -> 18.35 dB;
# the same frame with `--prior auto` at full resolution: 15.34 -> 14.22 dB (SSIM 0.724 -> 0.756, LPIPS 0.526 ->
# 0.507); the 4D model of 10 frames, 9 cameras: 20.16 -> 18.70 dB; LLFF 3 views with `--prior auto`: flower
# 20.90 -> 21.15, horns 20.36 -> 19.92 (docs/inward_rigs.md).
OPAQUE_MEASURED = ("a random one behind the photos, --effects background=opaque, measured mixed: Panoptic "
                   "+3.3 dB with exposure alone, -1.1 dB with the auto recipe; LLFF flower +0.25, horns -0.44")
# "mean": the training photos' mean colour as the scene's background, in training and in every render after it
# (evaluation, `gsgs eval` reads it from metrics.json). Where no splat covers a pixel of a novel view, the render
# shows the background; of all fixed colours the photos' mean is the best guess for what is there, where white
# is the worst for a grey room. `auto` on an inward shell's RGB photos. Measured (1000 steps, seed 0):
# panoptic_basketball frame 0, 9 cameras, --init mvs --techniques exposure, half resolution: 15.01 -> 22.72 dB
# (SSIM 0.580 -> 0.815, LPIPS 0.539 -> 0.373); the same frame under `--prior auto`: 15.34 -> 21.62 dB; its 4D
# model of 10 frames: 20.16 -> 24.15 dB (3 cameras: 17.45 -> 17.53); LLFF flower (3 views, `--prior auto`): 20.90 ->
# 20.95 dB (SSIM 0.671 -> 0.679, LPIPS 0.301 -> 0.292) but horns 20.36 -> 19.18 (SSIM and LPIPS better) --
# so `auto` uses it on inward shells (still or video), where test views look at what no training view covered;
# other rigs keep white (RGB orbits not measured) (docs/inward_rigs.md).
MEAN_ELSEWHERE = ("the photos' mean colour behind the splats, --effects background=mean, gained up to 7.9 dB on an "
                  "inward shell but measured mixed on forward-facing LLFF: flower +0.05 dB, horns -1.18")
MEAN_WHY = ("RGB views: the training photos' mean colour behind the splats (training and every render after it): "
            "what a novel view shows where no splat covers it")
# "sphere": the photos' mean colour to start, then a texture learned on the sphere through the cameras
# (gsgs_engine.train.background_sphere): a pixel no splat covers shows the texture where its ray leaves the sphere,
# which on an inward shell is the wall the cameras hang on, learned from the cameras across from it.
SPHERE_WHY = ("RGB views: a texture learned on the sphere through the cameras behind the splats (the wall of an "
              "inward shell), starting from the photos' mean colour; written beside the PLY")
# `auto` on an inward shell's RGB photos since session 35 (before: "mean"). Measured (1000 steps, seed 0, this
# VM): panoptic_basketball frame 0, 9 cameras, `gsgs train ... --train-views 9 --frames 0 --prior auto`: 21.02 ->
# 22.00 dB (SSIM 0.822 -> 0.828, LPIPS 0.428 -> 0.391); `gsgs bench dynamic` (10 frames, every model gets it):
# the 4D model 17.49 -> 19.69 (3 cameras), 21.30 -> 22.06 (6), 24.37 -> 24.84 (9), the per-frame static models
# +1.4 to +2.0 dB (docs/dynamic_panoptic.md, "Session 35"). Session 36 learns the texture at a fifth of the rate
# (background_sphere.LEARNING_RATE 0.01): frame 0 22.00 -> 23.30 dB; the 4D model over seeds 0-2 19.65 -> 19.97 /
# 22.49 -> 23.29 / 24.72 -> 25.19 dB with 3 / 6 / 9 cameras (docs/dynamic_panoptic.md, "Session 36").
SPHERE_MEASURED = ("measured against the mean colour on the Panoptic dome, seed 0: frame 0, 9 cameras 21.02 -> "
                   "23.30 dB; 10 frames, the 4D model 17.49 -> 19.94 / 21.30 -> 23.39 / 24.37 -> 25.12 dB with 3 / 6 "
                   "/ 9 cameras")
BACKGROUNDS = ("auto", "transparent", "opaque", "mean", "sphere", "fixed", "random")
# The rig. A converging rig (the optical axes meet) is an object orbit where the scene lies well inside the
# cameras' shell (NeRF-synthetic: the object), an inward shell where a real share of it reaches the shell:
# a dome or studio whose cameras hang on the walls they film (CMU Panoptic). There the walls, filmed by
# the cameras opposite, are reconstructed where the other cameras stand, and a novel camera on the shell
# sits inside them: with the renderer's default near plane (0.01) the splats in front of its lens fill
# the image (measured, panoptic_basketball frame 0, 9 cameras, plain 1000 steps: test cameras 0 and 15
# rendered black, 6.1 and 5.95 dB; the same model drawn with a near plane of 0.1 / 0.3 / 1.0 units gives
# 16.0 / 16.6 / 15.5 dB and 15.0 / 15.0 / 15.0 dB over the four test views, from 9.99).
# A point reaches the shell beyond SHELL_REACH x the cameras' median distance from the focus;
# the rig is a shell when at least SHELL_MIN_SHARE of the training views' SfM points do. Measured (frame 0 for
# Panoptic): panoptic_basketball 9 cameras 51% of 210 points, 6 cameras 63% of 71 (3 cameras triangulate no
# point: read from the photos, below); lego_200 8 views 0.6% of 170, blender_lego 8 views 0% of 329, blender_chair
# 8 views 0.2% of 640 (their points lie within 0.32 x the radius); LLFF is forward-facing (axes do not meet).
# Where too few points triangulate to measure (cameras far apart: 3 of Panoptic's, 120 degrees apart, give none),
# RGB photos of a converging rig count as a shell: they film their surroundings (a room, a dome, a studio),
# which lie at or beyond the cameras, while an object orbit on nothing comes as RGBA (NeRF-synthetic) and stays
# an orbit. The dense sweep cannot tell either: its consistent points on the dome with 3 / 6 / 9 cameras lie
# within 0.6 x the radius (the floor between the cameras; the walls do not match across 120 degrees), like
# lego's and chair's (0.3). Measured (docs/inward_rigs.md, session 36): Panoptic frame 0, 3 cameras,
# `--prior auto` read as an orbit 14.43 dB (below plain 3DGS's 15.38), as a shell 18.13.
SHELL_UNMEASURED_MEASURED = ("Panoptic frame 0, 3 cameras (no point triangulates), --prior auto, seed 0: read as an "
                             "orbit 14.43 dB, as a shell 18.13 (plain 3DGS 15.38)")
SHELL_REACH = 0.8
SHELL_MIN_SHARE = 0.2
# An inward shell's near plane: NEAR_FRACTION x the shell radius (the cameras' median distance from the
# focus), so it scales with the rig, whatever its units; nothing the cameras film lies that close to
# another camera of the shell but its own wall. It applies to novel views only (TrainConfig.novel_view_near).
NEAR_FRACTION = 0.1
RIGS = ("forward-facing", "object orbit", "inward shell")
SPARSE_DEPTH_MEASURED = ("measured to lower test PSNR (1000 steps, CPU: lego_200 8 views -1.57 dB depth-only, "
                         "and a further -1.01 dB on top of warp-inpaint; llff_flower 3 views -0.15 dB depth-only)")


@dataclass
class Effect:
    name: str
    enabled: bool
    value: object
    reason: str
    source: str = "auto"  # auto (measured / inferred) | user (override or explicit request)
    measured: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"enabled": bool(self.enabled), "value": self.value, "reason": self.reason, "source": self.source,
                "measured": self.measured}


@dataclass
class EffectPlan:
    effects: dict[str, Effect]
    seconds: float = 0.0  # time spent measuring (triangulation included)
    triangulation: object = None  # gsgs_engine.sfm.Triangulation when one was made; shared with init

    def __getitem__(self, name: str) -> Effect:
        return self.effects[name]

    def to_dict(self) -> dict:
        return {**{name: e.to_dict() for name, e in self.effects.items()}, "plan_seconds": round(self.seconds, 3)}

    def format(self) -> str:
        lines = ["effect plan:"]
        for name in EFFECTS:
            e = self.effects[name]
            state = "on " if e.enabled else "off"
            shown = ",".join(map(str, e.value)) if isinstance(e.value, list) else e.value
            value = "" if e.value in (None, True, False) or e.value == [] else f" = {shown}"
            lines.append(f"  {name:<13} {state}{value:<16} ({e.source}) {e.reason}")
        return "\n".join(lines)


# -- overrides -------------------------------------------------------------------------------------
def parse_overrides(text: str | None) -> dict:
    """"sh_degree=1,pseudo_views=off" -> {"sh_degree": 1, "pseudo_views": "off"}; names are checked."""
    out: dict = {}
    if not text:
        return out
    for item in text.split(","):
        item = item.strip()
        if not item:
            continue
        if "=" not in item:
            raise GsgsError(f"--effects {text!r}: {item!r} is not NAME=VALUE; names: {', '.join(EFFECTS)}")
        key, value = (s.strip() for s in item.split("=", 1))
        out[key] = int(value) if value.lstrip("-").isdigit() else value.lower()
    check_overrides(out)
    return out


_ON = ("on", "true", "yes", 1, True)
_OFF = ("off", "false", "no", "none", 0, False)


def check_overrides(overrides: dict) -> None:
    allowed = {
        "time": ("auto",) + _ON + _OFF, "sh_degree": ("auto", 0, 1, 2, 3),
        "background": BACKGROUNDS, "depth": ("auto",) + _ON + _OFF,
        "generator": ("auto", "warp-inpaint", "warp", "diffusion"), "rig": ("auto", "inward", "orbit"),
    }
    for key, value in overrides.items():
        if key not in EFFECTS:
            raise GsgsError(f"unknown effect {key!r} in --effects; known: {', '.join(EFFECTS)}")
        if key in ("position_lr", "attribute_lr"):
            flag = key.replace("_", "-") + "-scale"
            raise GsgsError(f"--effects {key}={value!r}: set it with --{flag} (a job: the setting \"{key}_scale\")")
        if key == "pseudo_views":
            if value in ("auto",) + _OFF or (isinstance(value, int) and value > 0):
                continue
            raise GsgsError(f"--effects pseudo_views={value!r}: use auto, off or a positive count")
        if value not in allowed[key]:
            raise GsgsError(f"--effects {key}={value!r}: use one of {', '.join(map(str, allowed[key]))}")


# -- measurements ------------------------------------------------------------------------------------
def coverage(cameras, near: float | None = None, far: float | None = None) -> dict:
    """View count and the median / max angle (deg) between a view and its nearest neighbour, seen from the focus."""
    n = len(cameras)
    if n < 2:
        return {"views": n, "nn_gap_median_deg": None, "nn_gap_max_deg": None, "focus": "one view"}
    if near and far:
        cameras = [replace(c, near=near, far=far) for c in cameras]
    focus, how = focus_point(cameras)
    rays = np.stack([c.center for c in cameras]) - focus
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    ang = np.degrees(np.arccos(np.clip(rays @ rays.T, -1.0, 1.0)))
    np.fill_diagonal(ang, np.inf)
    nn = ang.min(axis=1)
    return {"views": n, "nn_gap_median_deg": round(float(np.median(nn)), 2),
            "nn_gap_max_deg": round(float(nn.max()), 2), "focus": how}


def rig_layout(cameras, points=None, near: float | None = None, far: float | None = None, rgb: bool = False) -> dict:
    """What rig the cameras form: forward-facing, object orbit or inward shell (see SHELL_REACH), measured.

    `points` (N x 3, e.g. the training views' SfM points) tell an orbit from a shell: on a shell a
    share of them lies out at the cameras' distance from the focus. Without enough points a
    converging rig of `rgb` photos (no alpha) counts as a shell, of RGBA ones as an orbit
    ("points_at_shell" then absent, "unmeasured" set). "near" is the near plane a shell's renders
    need (None: the renderer's default).
    """
    if len(cameras) < 2:
        return {"rig": "object orbit", "focus": "one view", "near": None}
    if near and far:
        cameras = [replace(c, near=near, far=far) for c in cameras]
    focus, how = focus_point(cameras)
    if how != "optical axes intersection":
        return {"rig": "forward-facing", "focus": how, "near": None}
    radius = float(np.median([np.linalg.norm(c.center - focus) for c in cameras]))
    out = {"rig": "object orbit", "focus": how, "shell_radius": round(radius, 4), "near": None}
    pts = np.asarray(points if points is not None else np.zeros((0, 3)), dtype=np.float64).reshape(-1, 3)
    pts = pts[np.isfinite(pts).all(axis=1)]
    out["points"] = int(len(pts))
    if len(pts) < MIN_MEASURED_POINTS:
        out["unmeasured"] = True
        if rgb:
            out.update(rig="inward shell", near=round(NEAR_FRACTION * radius, 6))
        return out
    share = float(np.mean(np.linalg.norm(pts - focus, axis=1) >= SHELL_REACH * radius))
    out["points_at_shell"] = round(share, 4)
    if share >= SHELL_MIN_SHARE:
        out.update(rig="inward shell", near=round(NEAR_FRACTION * radius, 6))
    return out


def rig_effect(layout: dict, choice: str) -> Effect:
    """The plan's "rig" effect: on where an inward shell's near plane is in force."""
    if choice == "inward":
        if layout.get("shell_radius") is None:
            raise GsgsError("--effects rig=inward: the training cameras do not converge on a point (forward-facing "
                            "or one view), so there is no shell to derive a near plane from")
        near = round(NEAR_FRACTION * layout["shell_radius"], 6)
        return Effect("rig", True, "inward shell", f"--effects rig=inward: near plane {near:g}", "user",
                      {**layout, "rig": "inward shell", "near": near})
    if choice == "orbit":
        return Effect("rig", False, layout["rig"], "--effects rig=orbit: the renderer's default near plane", "user",
                      {**layout, "near": None})
    rig = layout["rig"]
    if rig == "inward shell" and layout.get("unmeasured"):
        why = (f"the optical axes meet; {layout.get('points', 0)} SfM points (< {MIN_MEASURED_POINTS}) cannot measure "
               "where the scene lies, and RGB photos of a converging rig film their surroundings (a room, a dome), "
               f"so an inward shell: novel views drawn with a near plane of {layout['near']:g} ({NEAR_FRACTION} x "
               f"the radius {layout['shell_radius']:.3g}); {SHELL_UNMEASURED_MEASURED}; --effects rig=orbit for an "
               "object on a plain backdrop")
    elif rig == "inward shell":
        why = (f"{layout['points_at_shell']:.0%} of {layout['points']} SfM points lie out at the cameras' shell "
               f"(>= {SHELL_REACH} x radius {layout['shell_radius']:.3g} from the focus; >= {SHELL_MIN_SHARE:.0%} "
               f"makes a shell): the walls the cameras hang on; novel views (evaluation, pseudo views) drawn with a "
               f"near plane of {layout['near']:g} ({NEAR_FRACTION} x the radius), so a camera on the shell does not "
               "draw the wall reconstructed around it")
    elif rig == "forward-facing":
        why = "the optical axes do not meet: " + layout["focus"]
    elif "points_at_shell" in layout:
        why = (f"the optical axes meet and {layout['points_at_shell']:.0%} of {layout['points']} SfM points lie out "
               f"at the cameras' shell (< {SHELL_MIN_SHARE:.0%}): the scene sits inside the rig")
    else:
        why = (f"the optical axes meet; {layout.get('points', 0)} SfM points (< {MIN_MEASURED_POINTS}) cannot tell a "
               "shell from an orbit, and RGBA views film an object on nothing: an orbit")
    return Effect("rig", rig == "inward shell", rig, why, measured=layout)


def _patch_mean(img: np.ndarray, u: float, v: float) -> np.ndarray | None:
    """Mean colour of the 3x3 pixels around continuous pixel coordinate (u, v) (pixel centres at .5)."""
    h, w = img.shape[:2]
    x, y = int(np.floor(u)), int(np.floor(v))
    if x < 1 or y < 1 or x > w - 2 or y > h - 2:
        return None
    return img[y - 1:y + 2, x - 1:x + 2].reshape(-1, 3).mean(0)


def _sample(img: np.ndarray, u: float, v: float) -> tuple[np.ndarray, float] | None:
    """(3x3 mean colour, its squared gradient magnitude per pixel of shift, averaged over channels)."""
    c = _patch_mean(img, u, v)
    around = [_patch_mean(img, u + du, v + dv) for du, dv in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    if c is None or any(a is None for a in around):
        return None
    gx = (around[0] - around[1]) / 2
    gy = (around[2] - around[3]) / 2
    return c, float((gx ** 2 + gy ** 2).mean())


def exposure_corrected_spread(obs: list[np.ndarray], num_views: int, iterations: int = 4,
                              noise: np.ndarray | None = None) -> dict:
    """Spread of point colours across views after removing a per-view, per-channel gain.

    `obs[p]` is a (k, 4) array of (view, r, g, b) for point p. Colour model:
    c[p, v] = a[p] * g[v] (channel-wise), g fitted by alternating medians of ratios, which is
    robust to the few misplaced observations at depth edges. `noise[p]` (optional) is the
    variance a point's colours would show from localisation error alone; it is removed in
    quadrature so texture edges do not read as view dependence. Returns the median and 90th
    percentile of the per-point RMS residual (unbiased over the k views) and the gains.
    """
    gains = np.ones((num_views, 3))
    for _ in range(iterations):
        ratios: list[list[np.ndarray]] = [[] for _ in range(num_views)]
        for o in obs:
            views, cols = o[:, 0].astype(int), o[:, 1:]
            albedo = (cols / gains[views]).mean(0)
            bright = albedo > 0.05  # dark colours give unstable ratios
            for vi, c in zip(views, cols):
                ratios[vi].append(np.where(bright, c / np.maximum(albedo, 1e-6), np.nan))
        for vi in range(num_views):
            if ratios[vi]:
                with np.errstate(all="ignore"):
                    g = np.nanmedian(np.stack(ratios[vi]), axis=0)
                gains[vi] = np.where(np.isfinite(g) & (g > 0), g, 1.0)
        gains /= np.exp(np.log(gains).mean(0))  # the gains' overall scale belongs to the albedo
    spreads = []
    for p, o in enumerate(obs):
        views, cols = o[:, 0].astype(int), o[:, 1:]
        corrected = cols / gains[views]
        res = corrected - corrected.mean(0)
        var = (res ** 2).sum(0).mean() / (len(corrected) - 1)
        if noise is not None:
            var = max(var - float(noise[p]), 0.0)
        spreads.append(float(np.sqrt(var)))
    s = np.asarray(spreads)
    return {"points": len(s), "spread_median": float(np.median(s)) if len(s) else None,
            "spread_p90": float(np.percentile(s, 90)) if len(s) else None, "gains": gains.round(4).tolist()}


def measure_view_dependence(images: list[np.ndarray], tracks: list[np.ndarray],
                            errors: np.ndarray | None = None) -> dict:
    """Colour spread of SfM points across the training views (see exposure_corrected_spread).

    `tracks[p]` is a (k, 3) array of (view index, u, v) as gsgs_engine.sfm.Triangulation gives;
    `errors[p]` its reprojection error in pixels. The localisation noise of an observation is
    (max(error, 0.5 px) x local colour gradient)^2: what sampling a textured spot that far off
    would change.
    """
    obs, noise = [], []
    for p, track in enumerate(tracks):
        rows, var = {}, []
        sigma = max(float(errors[p]) if errors is not None and p < len(errors) else 0.5, 0.5)
        for vi, u, v in np.asarray(track, dtype=np.float64).reshape(-1, 3):
            got = _sample(images[int(vi)], u, v)
            if got is not None and int(vi) not in rows:  # one observation per view
                rows[int(vi)] = got[0]
                var.append(sigma ** 2 * got[1])
        if len(rows) >= 2:
            obs.append(np.array([[vi, *c] for vi, c in rows.items()], dtype=np.float64))
            noise.append(float(np.mean(var)))
    return exposure_corrected_spread(obs, len(images), noise=np.asarray(noise))


def sh_degree_for_spread(spread: float) -> int:
    """Measured colour spread -> SH degree (thresholds SH_SPREAD)."""
    return int(sum(spread >= t for t in SH_SPREAD))


def identifiable_sh_degree(num_views: int) -> int:
    """Highest degree whose (d+1)^2 coefficients per channel the real views can pin down.

    A Gaussian is seen at most once per training view; with fewer views than coefficients the
    extra ones fit nothing and extrapolate freely at novel views (pseudo views are derived from
    the same photos, so they add no new view-dependent observations).
    """
    d = 0
    while d < 3 and (d + 2) ** 2 <= num_views:
        d += 1
    return d


def _truthy(value) -> bool | None:
    if value in _ON:
        return True
    if value in _OFF:
        return False
    return None


# -- the plan ---------------------------------------------------------------------------------------
def plan_effects(scene, train_config, prior_config=None, overrides: dict | None = None, train_views=None,
                 triangulation=None, log=print) -> EffectPlan:
    """Decide the effects (EFFECTS) for `scene` (see the module docstring); measures only what an auto choice needs.

    `triangulation` (a gsgs_engine.sfm.Triangulation of the training views) is made here when
    the SH degree or the depth source is auto and it is not given; `shared_triangulation(plan)`
    lets the trainer's initialisation reuse it instead of triangulating again.
    """
    from gsgs_engine.priors.config import PriorConfig, diffusion_configured

    t_start = time.perf_counter()
    prior_config = prior_config or PriorConfig(prior="none")
    overrides = dict(overrides or {})
    check_overrides(overrides)
    views = list(scene.train if train_views is None else train_views)
    if not views:
        raise GsgsError(f"{scene.source}: no training views to plan for; check --train-split / --train-ids")
    cams = [v.camera for v in views]
    effects: dict[str, Effect] = {}

    # time: 4D only when the training views carry at least two distinct times
    times = sorted({v.camera.time for v in views if v.camera.time is not None})
    want = _truthy(overrides.get("time", "auto"))
    if want is None:
        on = len(times) >= 2
        effects["time"] = Effect("time", on, "spacetime" if on else "static",
                                 f"{len(times)} distinct frame times in the training views" if times
                                 else "the views carry no time", measured={"distinct_times": len(times)})
    else:
        if want and len(times) < 2:
            raise GsgsError(f"--effects time=on: {scene.source} has {len(times)} distinct frame times; 4D needs a "
                            "multi-view video (frames with a time)")
        effects["time"] = Effect("time", want, "spacetime" if want else "static", "--effects time", "user",
                                 {"distinct_times": len(times)})

    # the prior's request bounds what auto may switch on
    requested = prior_config.prior
    sh_auto = overrides.get("sh_degree", "auto") == "auto"
    depth_want = _truthy(overrides.get("depth", "auto"))
    depth_possible = requested != "none" and prior_config.depth_reg and prior_config.depth_source != "none"
    depth_model = prior_config.depth_source not in ("auto", "none", "sparse")
    # SfM-point depth hurt in every lego_200 run (llff_flower: -0.15 dB alone, +0.26 on top of warp),
    # so `auto` does not pick it; the depth-only prior, --depth-source sparse or --effects depth=on do
    sparse_asked = requested == "depth" or prior_config.depth_source == "sparse" or depth_want is True
    rig_choice = overrides.get("rig", "auto")
    # an auto rig needs points only where the cameras converge (an orbit or a shell; forward-facing is geometry)
    converging = len(cams) >= 2 and focus_point(cams)[1] == "optical axes intersection"
    needs_points = (sh_auto or (depth_possible and depth_want is not False and not depth_model)
                    or (rig_choice == "auto" and converging))
    # the dense stereo init triangulates the same views for its depth ranges: it reuses this triangulation too
    if needs_points and triangulation is None and train_config.init in ("auto", "sfm", "mvs") and len(views) >= 2:
        from gsgs_engine.sfm import triangulate_with_known_poses

        log(f"effect plan: triangulating {len(views)} training views (shared with initialisation)")
        triangulation = triangulate_with_known_poses(views)
    num_points = None
    if triangulation is not None:
        num_points = int(len(triangulation.points))
    elif scene.points is not None:
        num_points = int(len(scene.points))

    # the rig: forward-facing, object orbit or inward shell (whose renders need a near plane)
    rig_points = triangulation.points if triangulation is not None else scene.points
    effects["rig"] = rig_effect(rig_layout(cams, rig_points, scene.near, scene.far, rgb=not scene.has_alpha),
                                rig_choice)

    # view-dependent colour: as many observations of a colour as distinct viewpoints (a video's camera at every
    # frame is one viewpoint)
    distinct = len(viewpoints(cams))
    cap = identifiable_sh_degree(distinct)
    if not sh_auto:
        d = int(overrides["sh_degree"])
        effects["sh_degree"] = Effect("sh_degree", d > 0, d, "--effects sh_degree", "user")
    else:
        measured: dict = {"identifiable_degree": cap, "num_train_views": len(views), "viewpoints": distinct}
        tracks = getattr(triangulation, "tracks", None) or []
        if len([t for t in tracks if len(t) >= 2]) >= MIN_MEASURED_POINTS:
            images = [v.image() for v in views]
            m = measure_view_dependence(images, tracks, getattr(triangulation, "errors", None))
            measured.update({k: (round(v, 4) if isinstance(v, float) else v) for k, v in m.items() if k != "gains"})
        if measured.get("points", 0) >= MIN_MEASURED_POINTS:
            wanted = sh_degree_for_spread(measured["spread_median"])
            why = (f"colour spread across views {measured['spread_median']:.3f} (median of {measured['points']} "
                   f"SfM points, exposure removed) -> degree {wanted}")
            high = measured.get(AUTO_ORBIT_SH_QUANTILE_KEY)
            limit = cap
            if (requested == "auto" and effects["rig"].value == "object orbit" and high is not None
                    and high >= SH_SPREAD[0]):
                # past the cap only where the bare views pin down degree 1 (4 views and up; 8 measured): 3 views stay
                # at degree 0
                wanted = max(wanted, AUTO_ORBIT_SH_DEGREE)
                limit = max(cap, AUTO_ORBIT_SH_DEGREE) if cap >= 1 else cap
                why += (f"; --prior auto on an object orbit: p90 spread {high:.3f} >= {SH_SPREAD[0]} (a tenth of the "
                        f"points change colour across views) -> at least degree {AUTO_ORBIT_SH_DEGREE}"
                        + (f", past the bare views' cap of {cap}" if 1 <= cap < AUTO_ORBIT_SH_DEGREE else "")
                        + f" ({AUTO_ORBIT_SH_MEASURED})")
            d = min(wanted, limit)
            if d < wanted:
                why += f"; capped at degree {limit} ({_viewpoint_count(len(views), distinct)})"
        else:
            d = cap
            why = (f"view dependence not measurable ({measured.get('points', 0)} points seen twice); degree "
                   f"{cap}, the most {_viewpoint_count(len(views), distinct)} identify")
        effects["sh_degree"] = Effect("sh_degree", d > 0, d, why, measured=measured)

    # background: RGBA views -> a random background each step so alpha is learned, not painted; an inward shell's
    # RGB views under the weights-free recipe -> the sphere (SPHERE_WHY), starting from the photos' mean colour;
    # "mean" and "opaque" only when asked (MEAN_WHY, OPAQUE_MEASURED)
    bg = overrides.get("background", "auto")
    if bg == "random":  # --random-background / the job setting: whichever of the two the views allow
        bg = "transparent" if scene.has_alpha else "opaque"
    if bg == "auto":
        if scene.has_alpha:
            effects["background"] = Effect("background", True, "transparent", "RGBA views: random background each "
                                           "step, alpha learned (composites in Blender)")
        elif requested == "auto" and effects["rig"].value == "inward shell":
            colour = photos_mean_colour(views)
            effects["background"] = Effect("background", True, "sphere", SPHERE_WHY + "; " + SPHERE_MEASURED,
                                           measured={"colour": colour})
        elif requested == "auto":
            effects["background"] = Effect("background", False, "fixed", f"RGB views, {effects['rig'].value}: "
                                           "the fixed background (" + MEAN_ELSEWHERE + ")")
        else:
            effects["background"] = Effect("background", False, "fixed", "RGB views: the background is part of the "
                                           "photos (" + OPAQUE_MEASURED + ")")
    else:
        if bg == "transparent" and not scene.has_alpha:
            raise GsgsError(f"--effects background=transparent: {scene.source} has no alpha channel; use opaque "
                            "(a random colour behind the photos, so every pixel is learned opaque) or fixed")
        if bg in ("opaque", "mean", "sphere") and scene.has_alpha:
            raise GsgsError(f"--effects background={bg}: {scene.source} has an alpha channel, which says where the "
                            "scene is see-through; use transparent (alpha learned) or fixed")
        measured = {"colour": photos_mean_colour(views)} if bg in ("mean", "sphere") else {}
        why = {"sphere": SPHERE_WHY, "mean": MEAN_WHY}.get(bg)
        effects["background"] = Effect("background", bg != "fixed", bg, "--effects background" +
                                       (f": {why}" if why else ""), "user", measured)

    # depth regularisation: only with a depth source
    if depth_want is False or not depth_possible:
        why = ("--effects depth=off" if depth_want is False else "prior none" if requested == "none"
               else "--no-depth-reg" if not prior_config.depth_reg else "--depth-source none")
        if depth_want is True:
            raise GsgsError(f"--effects depth=on contradicts {why}")
        effects["depth"] = Effect("depth", False, None, why, "user")
    elif depth_model:
        if not Path(prior_config.depth_source).is_dir():
            raise GsgsError(f"--depth-source {prior_config.depth_source!r}: folder not found; give a local "
                            "depth-estimation model folder, 'sparse', 'none' or 'auto'")
        effects["depth"] = Effect("depth", True, prior_config.depth_source, "depth-estimation model folder",
                                  "user" if depth_want else "auto")
    elif num_points is not None and num_points >= MIN_DEPTH_POINTS and not sparse_asked:
        effects["depth"] = Effect("depth", False, None, f"{num_points} SfM points could give depth, but SfM-point "
                                  f"depth is used only when asked for: {SPARSE_DEPTH_MEASURED}; --depth-source sparse "
                                  "or --effects depth=on turns it on", "auto", {"sfm_points": num_points})
    elif num_points is not None and num_points >= MIN_DEPTH_POINTS:
        effects["depth"] = Effect("depth", True, "sparse", f"{num_points} SfM points of the training views, "
                                  "densified per view", "user" if depth_want else "auto", {"sfm_points": num_points})
    else:
        if requested == "depth":  # the depth-only prior without depth is plain 3DGS: never train it silently
            raise GsgsError(f"--prior depth: no depth source ({num_points or 0} SfM points of the training views, "
                            f"fewer than {MIN_DEPTH_POINTS}, and no depth model); pass --depth-source MODEL_DIR, "
                            "or use --prior none")
        if depth_want is True:
            raise GsgsError(f"--effects depth=on: no depth source ({num_points or 0} SfM points, no depth model); "
                            "pass --depth-source MODEL_DIR")
        effects["depth"] = Effect("depth", False, None, f"no depth source: {num_points or 0} SfM points "
                                  f"(< {MIN_DEPTH_POINTS}) and no depth model", measured={"sfm_points": num_points})

    # pseudo views: only when the views are sparse for the scene's coverage (by viewpoint: a video's cameras once)
    cov = coverage(viewpoints(cams), scene.near, scene.far)
    gap = cov["nn_gap_median_deg"]
    sparse = cov["views"] < DENSE_MIN_VIEWS or (gap is not None and gap > DENSE_MAX_GAP_DEG)
    sparse_why = (f"{cov['views']} views (< {DENSE_MIN_VIEWS})" if cov["views"] < DENSE_MIN_VIEWS else
                  f"{cov['views']} views, nearest-view gap {gap} deg {'>' if sparse else '<='} {DENSE_MAX_GAP_DEG}")
    pv = overrides.get("pseudo_views", "auto")
    gen_possible = requested not in ("none", "depth")
    if pv in _OFF or not gen_possible:
        effects["pseudo_views"] = Effect("pseudo_views", False, 0, "--effects pseudo_views=off" if pv in _OFF
                                         else f"prior {requested}", "user", cov)
    elif isinstance(pv, int):
        effects["pseudo_views"] = Effect("pseudo_views", True, pv, "--effects pseudo_views", "user", cov)
    elif requested in ("warp", "diffusion"):
        effects["pseudo_views"] = Effect("pseudo_views", True, prior_config.num_pseudo,
                                         f"--prior {requested} asks for them", "user", cov)
    elif sparse and cov.get("focus") == "optical axes intersection" and not diffusion_configured(prior_config):
        rig_name = "inward-facing shell" if effects["rig"].value == "inward shell" else "orbiting"
        effects["pseudo_views"] = Effect("pseudo_views", False, 0, f"sparse {rig_name} rig (" + sparse_why + ") and no "
                                         "diffusion weights: " + WARP_MEASURED + "; --prior warp forces them",
                                         measured=cov)
    else:
        effects["pseudo_views"] = Effect("pseudo_views", sparse, prior_config.num_pseudo if sparse else 0,
                                         ("sparse: " if sparse else "dense: ") + sparse_why, measured=cov)

    # the generator: diffusion only with weights, else warp-inpaint
    g = overrides.get("generator", "auto")
    has_weights = diffusion_configured(prior_config)
    if not effects["pseudo_views"].enabled:
        effects["generator"] = Effect("generator", False, None, "no pseudo views", effects["pseudo_views"].source)
    elif g == "diffusion" or requested == "diffusion":
        if not has_weights:
            raise GsgsError("the diffusion generator needs local model folders: --diffusion-model and "
                            "--depth-adapter; or use --effects generator=warp-inpaint")
        effects["generator"] = Effect("generator", True, "diffusion", "requested", "user")
    elif g in ("warp", "warp-inpaint") or requested == "warp":
        effects["generator"] = Effect("generator", True, "warp-inpaint", "requested", "user")
    else:
        effects["generator"] = Effect("generator", True, "diffusion" if has_weights else "warp-inpaint",
                                      "diffusion weights configured" if has_weights
                                      else "no diffusion weights configured: weights-free warp-inpaint")
    # weights-free sparse-view techniques: as named, or under --prior auto the measured recipe on sparse static views
    asked = getattr(prior_config, "techniques", None)
    if asked is not None:
        names = [str(t) for t in asked]
        effects["techniques"] = Effect("techniques", bool(names), names,
                                       "--techniques / job setting" if names else "--techniques none", "user")
    elif requested != "auto":
        effects["techniques"] = Effect("techniques", False, [], f"prior {requested}: only techniques asked for by "
                                       "name (--techniques) run")
    elif effects["time"].enabled:
        per_frame = cameras_per_frame(views)
        few = per_frame <= AUTO_4D_FEW_CAMERAS
        effects["techniques"] = Effect("techniques", True, list(AUTO_4D_FEW_TECHNIQUES if few else AUTO_4D_TECHNIQUES),
                                       f"4D scene, {per_frame} cameras a frame: per-camera exposure with the per-frame "
                                       "dense init, " + (AUTO_4D_FEW_MEASURED if few else AUTO_4D_MEASURED),
                                       measured={"cameras_per_frame": per_frame})
    elif sparse:
        names, measured = AUTO_RIG_RECIPES.get(effects["rig"].value, (AUTO_TECHNIQUES, None))
        if int(train_config.iters) >= AUTO_LONG_STEPS:
            names, measured = AUTO_LONG_RIG_RECIPES.get(effects["rig"].value, (names, measured))
        effects["techniques"] = Effect("techniques", True, list(names),
                                       f"sparse: {sparse_why}; the measured weights-free recipe of {effects['rig'].value} "
                                       "rigs " + (f"with {measured}" if measured else "(docs/sparse_techniques.md)"),
                                       measured=cov)
    else:
        effects["techniques"] = Effect("techniques", False, [], "dense: " + sparse_why, measured=cov)
    # initialisation: dense multi-view stereo of the training views where --prior auto runs the recipe
    if train_config.init != "auto":
        effects["init"] = Effect("init", train_config.init == "mvs", train_config.init, "--init", "user")
    elif effects["time"].enabled and requested == "auto":
        effects["init"] = Effect("init", True, "mvs", "4D under --prior auto: multi-view stereo once per frame, each "
                                 "frame's points at its time; " + AUTO_4D_MEASURED)
    elif effects["techniques"].enabled and requested == "auto":
        # the recipe's techniques, or named ones (e.g. one option changed): --prior auto keeps its dense init
        effects["init"] = Effect("init", True, "mvs", "sparse static views under --prior auto: " + MVS_MEASURED)
    else:
        effects["init"] = Effect("init", False, "auto", "SfM points of the training views (else the source's "
                                 "points, else random)")
    effects["position_lr"] = position_lr_effect(train_config, effects, requested, sparse)
    effects["attribute_lr"] = attribute_lr_effect(train_config, effects, requested, sparse)
    return EffectPlan({name: effects[name] for name in EFFECTS}, time.perf_counter() - t_start, triangulation)


def apply_effect_plan(plan: EffectPlan, train_config, prior_config=None):
    """(TrainConfig, PriorConfig) that model exactly the plan's effects (copies; inputs untouched)."""
    from gsgs_engine.priors.config import PriorConfig

    from gsgs_engine.train.background_sphere import DEFAULT_WIDTH as SPHERE_WIDTH

    tc = replace(train_config, sh_degree=int(plan["sh_degree"].value),
                 random_background=plan["background"].value in ("transparent", "opaque"),
                 background_sphere=SPHERE_WIDTH if plan["background"].value == "sphere" else 0,
                 init=str(plan["init"].value))
    rig = plan.effects.get("rig")
    if rig is not None and rig.enabled and rig.measured.get("near"):
        tc.novel_view_near = float(rig.measured["near"])  # an inward shell's; otherwise the renderer's default
    position = plan.effects.get("position_lr")
    if position is not None:
        tc.position_lr_scale = float(position.value)
    attributes = plan.effects.get("attribute_lr")
    if attributes is not None:
        tc.attribute_lr_scale = float(attributes.value)
    pc = replace(prior_config or PriorConfig(prior="none"))
    gen, depth = plan["generator"].value, plan["depth"].value
    if gen:
        pc.prior = "diffusion" if gen == "diffusion" else "warp"
        pc.num_pseudo = int(plan["pseudo_views"].value)
    else:
        pc.prior = "depth" if depth else "none"
    pc.depth_reg = bool(depth)
    pc.depth_source = depth if depth else "none"
    pc.techniques = list(plan["techniques"].value)
    return tc, pc


def scene_for_plan(scene, plan: EffectPlan):
    """The scene the trainer should see: without frame times when the plan keeps it static, and on the
    plan's background colour when it is the photos' mean.

    The trainer builds the 4D (spacetime) model whenever a view carries a time, so a static
    plan for timed data (one frame in training, or `--effects time=off`) drops the times;
    the 4D parameters are then never allocated.
    """
    background = plan["background"]
    if background.value in ("mean", "sphere"):  # the sphere's texture starts from the photos' mean colour
        scene = replace(scene, background=np.asarray(background.measured["colour"], dtype=np.float32))
    if plan["time"].enabled or not scene.has_time:
        return scene
    views = [replace(v, camera=replace(v.camera, time=None)) for v in scene.views]
    return replace(scene, views=views)


def photos_mean_colour(views) -> list[float]:
    """The mean RGB colour of `views`' photos (each photo weighted equally), rounded to 1e-4."""
    if not views:
        raise GsgsError("the photos' mean colour needs at least one training view")
    means = [np.asarray(v.image(), dtype=np.float64).reshape(-1, 3).mean(axis=0) for v in views]
    colour = np.mean(means, axis=0)
    if not np.isfinite(colour).all():
        raise GsgsError(f"the training photos' mean colour is not finite ({colour.tolist()}); a photo holds NaN or "
                        "Inf pixels: check the image files, or pass --effects background=fixed")
    return [round(float(c), 4) for c in np.clip(colour, 0.0, 1.0)]


@contextlib.contextmanager
def shared_triangulation(plan: EffectPlan, views):
    """Let the trainer's SfM initialisation reuse the plan's triangulation of the same views.

    The trainer calls gsgs_engine.sfm.triangulate_known_poses at initialisation; this swaps in,
    for the duration, a function that answers for exactly these views (same names and
    cameras) from the plan and defers to the original for anything else. Costs nothing when
    the plan made no triangulation.
    """
    tri = plan.triangulation
    if tri is None:
        yield
        return
    import gsgs_engine.sfm as sfm

    original = sfm.triangulate_known_poses
    key = _views_key(views)

    def cached(vs, out_dir=None, **options):
        if out_dir is None and not options and _views_key(vs) == key:
            return tri.points, tri.colors
        return original(vs, out_dir=out_dir, **options)

    sfm.triangulate_known_poses = cached
    try:
        yield
    finally:
        sfm.triangulate_known_poses = original


def _views_key(views) -> tuple:
    out = []
    for v in views:
        cam = v.camera if hasattr(v, "camera") else v[0]
        out.append((cam.name, cam.width, cam.height, round(cam.fx, 6), tuple(np.round(cam.t, 6)),
                    tuple(np.round(cam.R, 6).ravel())))
    return tuple(out)


def add_effects_argument(parser) -> None:
    parser.add_argument("--effects", default=None, metavar="NAME=VALUE,...",
                        help="override the effect plan: rig=auto|inward|orbit, time=on|off, sh_degree=auto|0..3, "
                             "background=transparent|opaque|mean|"
                             "fixed, depth=on|off, pseudo_views=auto|off|N, generator=auto|warp-inpaint|diffusion")


def overrides_from_settings(settings: dict) -> dict:
    """Effect overrides of a job's settings (job.json): an explicit sh_degree, random_background -> a random
    background (transparent on RGBA views, opaque on RGB), then "effects" (a dict or the command line's
    NAME=VALUE,... text)."""
    out: dict = {}
    if settings.get("sh_degree") not in (None, "auto"):
        out["sh_degree"] = int(settings["sh_degree"])
    if settings.get("random_background"):
        out["background"] = "random"
    effects = settings.get("effects")
    out.update(parse_overrides(effects) if isinstance(effects, str) or effects is None else dict(effects))
    check_overrides(out)
    return out


def overrides_from_args(args) -> dict:
    """Effect overrides of a `gsgs train` command line: a preset's, then --sh-degree, then --effects (typed wins)."""
    out = dict(getattr(args, "effects_overrides", None) or {})
    if getattr(args, "sh_degree", None) is not None:
        out["sh_degree"] = int(args.sh_degree)
    out.update(parse_overrides(getattr(args, "effects", None)))
    check_overrides(out)
    return out
