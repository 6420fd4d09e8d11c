"""4D results on the Blender timeline: an engine-written SpacetimeGS PLY imported through the add-on
follows the scene frame exactly as SpacetimeModel.at_time (positions, rotations, opacities).

Benchmark (no test): PYTHONPATH=. python tests/test_blender_timeline.py [N] times frame updates of N splats."""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest
import torch

from gsgs_engine.gaussians import GaussianModel
from gsgs_engine.io.ply import write_gaussian_ply
from gsgs_engine.spacetime import (PLY_TEMPORAL_FIELDS, SpacetimeModel, polynomial_position, rotation_at,
                                   temporal_opacity)

bpy = pytest.importorskip("bpy")
import gsgs_blender  # noqa: E402  (needs bpy)
from gsgs_blender import splat_import, timeline  # noqa: E402

pytestmark = pytest.mark.blender
FRAMES = (1, 25)


@pytest.fixture()
def scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    gsgs_blender.register()
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    scene.frame_set(FRAMES[0])
    yield scene
    gsgs_blender.unregister()
    bpy.ops.wm.read_factory_settings(use_empty=True)


def _model(n: int, seed: int = 0) -> SpacetimeModel:
    g = torch.Generator().manual_seed(seed)
    base = GaussianModel.from_points(torch.randn(n, 3, generator=g).numpy(), None, 1)
    m = SpacetimeModel.from_static(base, torch.rand(n, generator=g).numpy(), 0.3)
    with torch.no_grad():
        m.params["quats"].copy_(torch.randn(n, 4, generator=g))
        m.params["opacity_logits"].copy_(torch.randn(n, generator=g) * 2)
        m.params["t_log_scale"].copy_(torch.log(0.1 + torch.rand(n, generator=g)))
        m.params["motion"].copy_(torch.randn(n, 3, 3, generator=g) * 0.5)
        m.params["omega"].copy_(torch.randn(n, 4, generator=g))
    return m


def _import(tmp_path, model, name="dyn"):
    path = tmp_path / f"{name}.ply"
    write_gaussian_ply(path, model.to_ply())
    obj, _ = splat_import.import_splats(path, max_display=0)
    return obj


def _attr(mesh, name: str, width: int) -> np.ndarray:
    return timeline._read(mesh, name, width)


def _assert_at_time(obj, model, t):
    means, quats, _, opac = (x.detach().numpy() for x in model.at_time(t))
    mesh = obj.data
    np.testing.assert_allclose(_attr(mesh, "position", 3), means, atol=1e-5)
    q = _attr(mesh, "rotation", 4)
    sign = np.sign((q * quats).sum(axis=1, keepdims=True))  # q and -q are the same rotation
    np.testing.assert_allclose(q * sign, quats, atol=1e-5)
    np.testing.assert_allclose(_attr(mesh, "opacity", 1), opac, atol=1e-5)


def test_field_names_and_equations_mirror_the_engine():
    assert timeline.TEMPORAL_FIELDS == PLY_TEMPORAL_FIELDS
    rng = np.random.default_rng(1)
    n = 64
    means, motion = rng.normal(size=(n, 3)), rng.normal(size=(n, 3, 3))
    quats, omega = rng.normal(size=(n, 4)), rng.normal(size=(n, 4))
    logits, t_center, t_scale = rng.normal(size=n), rng.random(n), 0.1 + rng.random(n)
    dt = 0.7 - t_center
    f32 = lambda a: np.asarray(a, np.float32)  # noqa: E731
    tt = lambda a: torch.from_numpy(f32(a))  # noqa: E731
    np.testing.assert_allclose(timeline.polynomial_position(f32(means), f32(motion), f32(dt)),
                               polynomial_position(tt(means), tt(motion), tt(dt)).numpy(), atol=1e-6)
    np.testing.assert_allclose(timeline.rotation_at(f32(quats), f32(omega), f32(dt)),
                               rotation_at(tt(quats), tt(omega), tt(dt)).numpy(), atol=1e-6)
    np.testing.assert_allclose(timeline.temporal_opacity(f32(logits), f32(t_center), f32(t_scale), 0.7),
                               temporal_opacity(tt(logits), tt(t_center), tt(t_scale), 0.7).numpy(), atol=1e-6)
    assert timeline.frame_to_time(13, 1, 25) == pytest.approx(0.5)
    assert timeline.frame_to_time(-5, 1, 25) == 0.0 and timeline.frame_to_time(99, 1, 25) == 1.0
    assert timeline.frame_to_time(4, 4, 4) == 0.0  # a one-frame range


def test_4d_ply_plays_on_the_timeline(scene, tmp_path):
    model = _model(200)
    scene.frame_set(7)
    obj = _import(tmp_path, model)
    assert obj[timeline.IS_4D] and (obj[timeline.FRAME_START], obj[timeline.FRAME_END]) == FRAMES
    _assert_at_time(obj, model, 6 / 24)  # evaluated at the current frame on import
    scale = _attr(obj.data, "scale", 3).copy()
    for frame in (1, 13, 20, 25):
        scene.frame_set(frame)
        _assert_at_time(obj, model, (frame - 1) / 24)
    scene.frame_set(40)  # past the range: the last pose, not an extrapolated cubic
    _assert_at_time(obj, model, 1.0)
    np.testing.assert_array_equal(_attr(obj.data, "scale", 3), scale)  # SpacetimeGS-lite scales are static

    # The geometry-nodes instances follow: the depsgraph re-evaluates after the handler's writes.
    scene.frame_set(19)
    geometry = obj.evaluated_get(bpy.context.evaluated_depsgraph_get()).evaluated_geometry()
    instances = geometry.instances_pointcloud()
    m = _attr(instances, "instance_transform", 16).reshape(-1, 4, 4).transpose(0, 2, 1)
    np.testing.assert_allclose(m[:, :3, 3], model.at_time(18 / 24)[0].detach().numpy(), atol=1e-5)
    np.testing.assert_allclose(_attr(instances, "opacity", 1), model.at_time(18 / 24)[3].detach().numpy(), atol=1e-5)


def test_retimed_range_and_result_panel(scene, tmp_path):
    from test_blender_addon import _draw_all

    model = _model(30, seed=2)
    obj = _import(tmp_path, model)
    obj[timeline.FRAME_START], obj[timeline.FRAME_END] = 101, 111
    scene.frame_set(106)
    _assert_at_time(obj, model, 0.5)
    scene.gsgs.result_object = obj
    labels = [kw.get("text", "") for name, _, kw in _draw_all(bpy.context) if name == "label"]
    assert "4D: plays on the timeline (frames 101-111)" in labels


def test_static_ply_is_not_touched(scene, tmp_path):
    static = _model(50, seed=3)
    path = tmp_path / "static.ply"
    ply = static.to_ply()
    ply.extra = {}
    write_gaussian_ply(path, ply)
    obj, _ = splat_import.import_splats(path, max_display=0)
    assert not obj.get(timeline.IS_4D) and not timeline.playable(obj)
    before = {name: _attr(obj.data, name, w).copy() for name, w in (("position", 3), ("rotation", 4), ("opacity", 1))}
    scene.frame_set(17)
    for name, values in before.items():
        np.testing.assert_array_equal(_attr(obj.data, name, values.shape[1] if values.ndim > 1 else 1), values)


def test_handler_registered_once_and_removed():
    count = lambda: sum(timeline._ours(h) for h in bpy.app.handlers.frame_change_post)  # noqa: E731
    bpy.ops.wm.read_factory_settings(use_empty=True)
    for _ in range(2):
        gsgs_blender.register()
        timeline.register_handler()  # again, as a reloaded add-on would
        assert count() == 1
        bpy.ops.wm.read_factory_settings(use_empty=True)  # persistent: survives loading a file
        assert count() == 1
        gsgs_blender.unregister()
        assert count() == 0


def test_deleted_or_stripped_objects_do_not_break_playback(scene, tmp_path):
    model = _model(40, seed=4)
    gone = _import(tmp_path, model, "gone")
    stripped = _import(tmp_path, model, "stripped")
    kept = _import(tmp_path, model, "kept")
    bpy.data.objects.remove(gone, do_unlink=True)
    stripped.data.attributes.remove(stripped.data.attributes["omega_2"])  # a user deleted an attribute
    before = _attr(stripped.data, "position", 3).copy()
    scene.frame_set(21)
    _assert_at_time(kept, model, 20 / 24)
    np.testing.assert_array_equal(_attr(stripped.data, "position", 3), before)  # skipped, not an error


def _benchmark(n: int) -> None:
    import tempfile
    from pathlib import Path

    bpy.ops.wm.read_factory_settings(use_empty=True)
    gsgs_blender.register()
    with tempfile.TemporaryDirectory() as tmp:
        obj = _import(Path(tmp), _model(n))
        scene = bpy.context.scene
        handler, frame_set = [], []
        for frame in range(scene.frame_start + 1, scene.frame_start + 11):
            scene.frame_current = frame
            t0 = time.perf_counter()
            timeline.on_frame_change(scene)  # what the handler adds to a frame change
            handler.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            scene.frame_set(frame + 20)  # the whole frame change: handler + depsgraph (geometry nodes)
            frame_set.append(time.perf_counter() - t0)
        ms = lambda ts: f"median {np.median(ts) * 1000:.1f} ms, min {min(ts) * 1000:.1f} ms"  # noqa: E731
        print(f"{len(obj.data.vertices):,} splats, {len(handler)} frames: handler {ms(handler)}; "
              f"scene.frame_set {ms(frame_set)}")


if __name__ == "__main__":
    torch.set_num_threads(1)
    _benchmark(int(sys.argv[1]) if len(sys.argv) > 1 else 100_000)
