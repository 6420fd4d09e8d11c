"""4D splats on the timeline: the SpacetimeGS-lite motion of gsgs_engine/spacetime.py, in numpy.

A 4D PLY (`SpacetimeModel.to_ply`) stores each Gaussian at its temporal centre plus `t_center`,
`t_scale` (log), `motion_0..8` (b_1..b_3, x y z each) and `omega_0..3`. The importer keeps those
as point attributes next to the rest values (`gsgs_rest_position`, `gsgs_rest_rotation` (raw, not
normalised), `gsgs_opacity_logit`); on every frame change a handler evaluates each 4D object at
the frame's normalised time and writes `position`, `rotation` and `opacity`, the attributes the
geometry-nodes group and the material read. numpy at module level, bpy inside functions, no torch.

Time: the engine normalises a capture so its first frame is t = 0 and its last t = 1. An
imported object maps the frame range in its custom properties `gsgs_frame_start` /
`gsgs_frame_end` (the scene's frame range at import; edit them to retime) onto [0, 1]; frames
outside the range hold the first / last pose rather than extrapolating the cubic.
"""

from __future__ import annotations

import numpy as np

# The PLY names of gsgs_engine/spacetime.py (PLY_TEMPORAL_FIELDS; a test keeps them equal).
T_CENTER, T_SCALE = "t_center", "t_scale"
MOTION_DEGREE = 3
MOTION = tuple(f"motion_{i}" for i in range(3 * MOTION_DEGREE))
OMEGA = tuple(f"omega_{i}" for i in range(4))
TEMPORAL_FIELDS = (T_CENTER, T_SCALE) + MOTION + OMEGA
REST_POSITION, REST_ROTATION, OPACITY_LOGIT = "gsgs_rest_position", "gsgs_rest_rotation", "gsgs_opacity_logit"
IS_4D, FRAME_START, FRAME_END = "gsgs_4d", "gsgs_frame_start", "gsgs_frame_end"


# -- the 4D equations, as gsgs_engine/spacetime.py (METHOD.md "4D") ---------------------------------
def polynomial_position(means: np.ndarray, motion: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """position(t) = mu + sum_{k=1..3} b_k (t - mu_t)^k. motion: [N, 3, 3] = b_k rows."""
    powers = np.stack([dt ** k for k in range(1, motion.shape[1] + 1)], axis=1)  # [N, K]
    return means + (powers[:, :, None] * motion).sum(axis=1)


def rotation_at(quats: np.ndarray, omega: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """rotation(t) = normalise(q + omega (t - mu_t))."""
    q = quats + omega * dt[:, None]
    return q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), np.float32(1e-12))


def temporal_opacity(opacity_logits: np.ndarray, t_center: np.ndarray, t_scale: np.ndarray, t: float) -> np.ndarray:
    """opacity(t) = sigmoid(o) * exp(-((t - mu_t) / s_t)^2); t_scale is s_t (not its log)."""
    return 1.0 / (1.0 + np.exp(-opacity_logits)) * np.exp(-((np.float32(t) - t_center) / t_scale) ** 2)


def frame_to_time(frame: float, frame_start: float, frame_end: float) -> float:
    """Scene frame -> the engine's normalised time: frame_start -> 0, frame_end -> 1, clamped."""
    if frame_end <= frame_start:
        return 0.0
    return float(min(1.0, max(0.0, (frame - frame_start) / (frame_end - frame_start))))


def is_spacetime(g) -> bool:
    """True when a GaussianPly carries every temporal field of a gsgs 4D result."""
    return all(name in (g.extra or {}) for name in TEMPORAL_FIELDS)


def rest_arrays(g) -> dict[str, tuple[str, np.ndarray]]:
    """The values at each Gaussian's temporal centre, kept for evaluating any frame (splat_arrays format)."""
    f32 = lambda a: np.ascontiguousarray(a, dtype=np.float32).ravel()  # noqa: E731
    return {REST_POSITION: ("FLOAT_VECTOR", f32(g.positions)), REST_ROTATION: ("QUATERNION", f32(g.quats_wxyz)),
            OPACITY_LOGIT: ("FLOAT", f32(g.opacity_logits))}


# -- Blender: read the stored fields, write the frame's values --------------------------------------
def _read(mesh, name: str, width: int) -> np.ndarray:
    attr = mesh.attributes[name]
    out = np.empty(len(attr.data) * width, np.float32)
    attr.data.foreach_get("vector" if attr.data_type == "FLOAT_VECTOR" else "value", out)
    return out.reshape(-1, width) if width > 1 else out


def evaluate_mesh(mesh, t: float) -> None:
    """Write position / rotation / opacity of the splat mesh at normalised time t (vectorised)."""
    t_center = _read(mesh, T_CENTER, 1)
    dt = np.float32(t) - t_center
    motion = np.stack([_read(mesh, name, 1) for name in MOTION], axis=1).reshape(-1, MOTION_DEGREE, 3)
    omega = np.stack([_read(mesh, name, 1) for name in OMEGA], axis=1)
    means = polynomial_position(_read(mesh, REST_POSITION, 3), motion, dt)
    quats = rotation_at(_read(mesh, REST_ROTATION, 4), omega, dt)
    opacity = temporal_opacity(_read(mesh, OPACITY_LOGIT, 1), t_center, np.exp(_read(mesh, T_SCALE, 1)), t)
    mesh.attributes["position"].data.foreach_set("vector", np.ascontiguousarray(means, np.float32).ravel())
    mesh.attributes["rotation"].data.foreach_set("value", np.ascontiguousarray(quats, np.float32).ravel())
    mesh.attributes["opacity"].data.foreach_set("value", np.ascontiguousarray(opacity, np.float32))
    mesh.update()


def playable(obj) -> bool:
    """A 4D splat object whose mesh still has every field the evaluation reads."""
    if obj.type != "MESH" or not obj.get(IS_4D) or obj.mode == "EDIT":
        return False
    names = obj.data.attributes.keys()
    return all(n in names for n in TEMPORAL_FIELDS + (REST_POSITION, REST_ROTATION, OPACITY_LOGIT,
                                                      "rotation", "opacity"))


def update_object(obj, frame: float) -> float:
    """Evaluate a 4D splat object at a scene frame; returns the normalised time used."""
    t = frame_to_time(frame, obj.get(FRAME_START, 0), obj.get(FRAME_END, 0))
    evaluate_mesh(obj.data, t)
    return t


def on_frame_change(scene, depsgraph=None) -> None:
    """frame_change_post handler: every 4D splat object of the scene follows the frame."""
    done = set()
    for obj in scene.objects:
        if playable(obj) and obj.data.as_pointer() not in done:  # a mesh shared by objects once
            done.add(obj.data.as_pointer())
            update_object(obj, scene.frame_current_final)


def _ours(handler) -> bool:
    # By name, so a handler left by an earlier (reloaded) copy of this module is found too.
    return getattr(handler, "__name__", "") == on_frame_change.__name__ and \
        getattr(handler, "__module__", "") == __name__


def register_handler() -> None:
    import bpy

    unregister_handler()
    bpy.app.handlers.frame_change_post.append(bpy.app.handlers.persistent(on_frame_change))


def unregister_handler() -> None:
    import bpy

    handlers = bpy.app.handlers.frame_change_post
    for handler in [h for h in handlers if _ours(h)]:
        handlers.remove(handler)
