"""Gaussian-splat PLY -> a vertices-only mesh with per-point attributes, shown by geometry nodes.

Attributes (point domain): `opacity` (sigmoid of the logit), `scale` (exp of the log
scale, FLOAT_VECTOR), `rotation` (unit quaternion, QUATERNION), `color` (the view-independent
colour 0.5 + C0 * SH DC, converted from the engine's sRGB values to linear, FLOAT_COLOR),
`sh_dc` and `sh_rest_01..` (raw SH coefficients, FLOAT_VECTOR, one per coefficient),
`gsgs_lod_rank` (0 = most visible by opacity x footprint, up to 1: the viewport shows the
lowest ranks first) and every unknown PLY property (e.g. 4D motion fields) as a FLOAT attribute.
A gsgs 4D PLY also keeps its rest values and plays on the timeline (timeline.py).
Everything is written with foreach_set: no Python loop over points.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError

SH_C0 = 0.28209479177387814  # Y_0^0, the constant SH basis function
DEFAULT_MAX_DISPLAY = 200_000
# Above this many splats the import warns: Cycles memory and render time grow with the count, and
# counts like this from a short, few-photo job usually mean the seeding ran away (see the warning).
LARGE_COUNT = 500_000
RESERVED = {"position", "opacity", "scale", "rotation", "color", "sh_dc", ".select_vert", "sharp_face",
            "gsgs_lod_rank", "gsgs_rgb", "gsgs_proxy"}
# Substrings of per-point properties that 4D (spacetime) results add; a full gsgs 4D set plays back.
TEMPORAL_HINTS = ("time", "t_center", "t_scale", "trbf", "motion", "omega", "velocity")


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-x))


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 decoding (the engine's colours are display-referred sRGB values)."""
    c = np.maximum(c, 0.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def lod_rank(opacity: np.ndarray, scales: np.ndarray) -> np.ndarray:
    """Rank in [0, 1) by visibility, most visible first: opacity x footprint radius (the geometric
    mean of the two largest scales: a flat disc seen face-on covers that much)."""
    n = opacity.shape[0]
    s = np.sort(np.abs(scales), axis=1)
    priority = opacity * np.sqrt(s[:, 1] * s[:, 2])
    priority = np.where(np.isfinite(priority), priority, -np.inf)
    order = np.argsort(-priority, kind="stable")
    rank = np.empty(n, np.float32)
    rank[order] = np.arange(n, dtype=np.float32) / np.float32(max(n, 1))
    return rank


def count_warning(n: int, path) -> str | None:
    """The Info-line warning for a splat count large enough to make Blender slow, else None."""
    if n <= LARGE_COUNT:
        return None
    return (f"{path}: {n:,} splats is a lot (renders and memory grow with it; the viewport shows the most "
            f"visible {DEFAULT_MAX_DISPLAY:,} by default). From a short job on few photos this usually means the "
            "generated views seeded Gaussians into empty regions; train with fewer pseudo views or the "
            "'fast'/'balanced' preset")


def splat_arrays(g) -> dict[str, tuple[str, np.ndarray]]:
    """GaussianPly -> {attribute name: (Blender data type, flat float32 array)} (no bpy needed)."""
    n = g.positions.shape[0]
    # float32 throughout: Blender stores float32, and a million splats stay quick.
    quats = np.asarray(g.quats_wxyz, dtype=np.float32)
    norm = np.linalg.norm(quats, axis=1, keepdims=True)
    quats = np.where(norm > 1e-12, quats / np.maximum(norm, 1e-12), np.array([1, 0, 0, 0], np.float32))
    rgb = srgb_to_linear(np.clip(0.5 + np.float32(SH_C0) * np.asarray(g.sh_dc, dtype=np.float32), 0.0, 1.0))
    rgba = np.concatenate([rgb, np.ones((n, 1), np.float32)], axis=1)
    opacity = sigmoid(np.asarray(g.opacity_logits, dtype=np.float32))
    scales = np.exp(np.asarray(g.log_scales, dtype=np.float32))
    out = {
        "opacity": ("FLOAT", opacity),
        "scale": ("FLOAT_VECTOR", scales),
        "gsgs_lod_rank": ("FLOAT", lod_rank(opacity, scales)),
        "rotation": ("QUATERNION", quats),
        "color": ("FLOAT_COLOR", rgba),
        "sh_dc": ("FLOAT_VECTOR", np.asarray(g.sh_dc)),
    }
    rest = np.asarray(g.sh_rest)
    for k in range(rest.shape[1]):
        out[f"sh_rest_{k + 1:02d}"] = ("FLOAT_VECTOR", rest[:, k, :])
    for name, values in (g.extra or {}).items():
        key = f"ply_{name}" if name in RESERVED or name in out else name
        out[key] = ("FLOAT", np.asarray(values))
    return {k: (t, np.ascontiguousarray(v, dtype=np.float32).ravel()) for k, (t, v) in out.items()}


def temporal_fields(g) -> list[str]:
    return sorted(name for name in (g.extra or {}) if any(h in name.lower() for h in TEMPORAL_HINTS))


def import_splats(path: str | Path, collection=None, name: str | None = None,
                  max_display: int = DEFAULT_MAX_DISPLAY, size: float | None = None):
    """Read a Gaussian PLY and create the splat object; returns (object, seconds spent)."""
    import bpy

    from gsgs_engine.io.ply import read_gaussian_ply

    from . import node_groups, timeline

    path = Path(path)
    if not path.is_file():
        raise GsgsError(f"{path}: no such PLY file; pick a Gaussian-splat .ply (e.g. a job's result/point_cloud.ply)")
    t0 = time.perf_counter()
    g = read_gaussian_ply(path)
    n = int(g.positions.shape[0])
    if n == 0:
        raise GsgsError(f"{path}: the PLY has no points; train longer or pick another file")
    arrays = splat_arrays(g)
    is_4d = timeline.is_spacetime(g)
    if is_4d:
        arrays.update(timeline.rest_arrays(g))

    mesh = bpy.data.meshes.new(name or path.stem)
    mesh.vertices.add(n)
    mesh.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(g.positions, dtype=np.float32).ravel())
    for attr_name, (data_type, flat) in arrays.items():
        attr = mesh.attributes.new(attr_name, data_type, "POINT")
        key = {"FLOAT": "value", "QUATERNION": "value", "FLOAT_VECTOR": "vector", "FLOAT_COLOR": "color"}[data_type]
        attr.data.foreach_set(key, flat)
    mesh.update()

    obj = bpy.data.objects.new(name or path.stem, mesh)
    (collection or bpy.context.scene.collection).objects.link(obj)
    obj["gsgs_source"] = str(path)
    obj["gsgs_sh_degree"] = int(g.sh_degree)
    obj["gsgs_count"] = n
    temporal = temporal_fields(g)
    if temporal:
        obj["gsgs_temporal_fields"] = temporal
    if is_4d:
        scene = bpy.context.scene
        obj[timeline.IS_4D] = True
        obj[timeline.FRAME_START], obj[timeline.FRAME_END] = scene.frame_start, scene.frame_end
        timeline.update_object(obj, scene.frame_current_final)
    node_groups.add_splat_modifier(obj, display_ratio=display_ratio_for(n, max_display),
                                   size=node_groups.DEFAULT_SIZE if size is None else size)
    return obj, time.perf_counter() - t0


def display_ratio_for(count: int, max_display: int) -> float:
    return min(1.0, max_display / count) if count and max_display > 0 else 1.0
