"""Scale-free numerics: a scene far smaller or larger than usual is trained in rescaled units.

The renderer's near plane (0.01), the nearest-neighbour floor of the initial scales, the
random-init box floors and a few more constants are world lengths tuned for scenes whose
cameras stand metres apart (NeRF-synthetic: 3.4 units; LLFF: 3.4). A copy of a scene with
every translation multiplied by 1e-3 put every Gaussian inside the near plane and trained
to a blank image. Rather than thread a scale through every such constant, `normalise_scene`
divides the scene's lengths (camera translations, near/far, sparse points) by a power of ten
`world_scale` when the cameras' spread lies outside COMFORT, so training always sees spreads
of 0.05..5000 units; scenes inside that range (all the shared data) are untouched, bit for bit.
Everything a user receives goes back to world units: `ply_to_world` for point_cloud.ply,
`ply_to_internal` when `gsgs eval` reads one, `camera_dicts_to_internal` for authored poses.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

COMFORT = (0.05, 5000.0)  # median distance of the camera centres from their mean, in world units


def camera_spread(cameras) -> float:
    """Median distance of the camera centres from their mean (0 for fewer than two cameras)."""
    if len(cameras) < 2:
        return 0.0
    centers = np.stack([c.center for c in cameras])
    return float(np.median(np.linalg.norm(centers - centers.mean(0), axis=1)))


def unit_for(spread: float) -> float:
    """The power of ten to divide lengths by: 1 inside COMFORT, else one bringing the spread to [1, 10)."""
    if not math.isfinite(spread) or spread <= 0 or COMFORT[0] <= spread < COMFORT[1]:
        return 1.0
    return 10.0 ** math.floor(math.log10(spread))


def _scaled_camera(cam, s: float):
    return replace(cam, t=cam.t / s, near=None if cam.near is None else cam.near / s,
                   far=None if cam.far is None else cam.far / s)


def normalise_scene(scene):
    """`scene` in internal units (lengths / world_scale); scene.world_scale records the factor."""
    s = unit_for(camera_spread([v.camera for v in scene.views]))
    if s == 1.0:
        return scene
    scene.views = [replace(v, camera=_scaled_camera(v.camera, s)) for v in scene.views]
    if scene.points is not None:
        scene.points = (np.asarray(scene.points, dtype=np.float64) / s).astype(np.float32)
    scene.near = None if scene.near is None else scene.near / s
    scene.far = None if scene.far is None else scene.far / s
    scene.world_scale = float(getattr(scene, "world_scale", 1.0)) * s
    return scene


MOTION_PREFIX = "motion_"  # gsgs_engine.spacetime.PLY_MOTION: polynomial motion coefficients, lengths per time^k


def _rescaled_ply(ply, factor: float):
    if factor == 1.0:
        return ply
    extra = dict(ply.extra)
    for name in extra:
        if name.startswith(MOTION_PREFIX):
            extra[name] = (np.asarray(extra[name], dtype=np.float64) * factor).astype(extra[name].dtype)
    return replace(ply, positions=(ply.positions.astype(np.float64) * factor).astype(np.float32),
                   log_scales=(ply.log_scales + np.float32(math.log(factor))).astype(np.float32), extra=extra)


def ply_to_world(ply, world_scale: float):
    """A GaussianPly trained in internal units, in world units (what point_cloud.ply holds)."""
    return _rescaled_ply(ply, float(world_scale))


def ply_to_internal(ply, world_scale: float):
    """A world-unit GaussianPly (point_cloud.ply) in a normalised scene's internal units."""
    return _rescaled_ply(ply, 1.0 / float(world_scale))


def _scaled_camera_dicts(dicts, divide_by: float):
    if not dicts or divide_by == 1.0:
        return dicts
    out = []
    for d in dicts:
        d = dict(d)
        if "t" in d:
            d["t"] = [float(x) / divide_by for x in d["t"]]
        for key in ("near", "far"):
            if d.get(key) is not None:
                d[key] = float(d[key]) / divide_by
        out.append(d)
    return out


def camera_dicts_to_internal(dicts, world_scale: float):
    """Camera.to_dict entries in world units (job.json pseudo_poses) in internal units."""
    return _scaled_camera_dicts(dicts, float(world_scale))


def camera_dicts_to_world(dicts, world_scale: float):
    """Camera.to_dict entries in internal units (the pseudo views of a round) in world units."""
    return _scaled_camera_dicts(dicts, 1.0 / float(world_scale))
