"""Dense (MVS) initialisation on synthetic views of a known textured plane, the fallback, the budget."""

from __future__ import annotations

import numpy as np
import pytest

from gsgs_engine.cameras import Camera
from gsgs_engine.init.mvs import MVSConfig, dense_initial_model, dense_points, working_side
from gsgs_engine.io.scene import Scene, View

PLANE_Z = 5.0


def texture(size: int = 256, seed: int = 0) -> np.ndarray:
    import cv2

    noise = np.random.default_rng(seed).uniform(0, 1, (size // 8, size // 8, 3)).astype(np.float32)
    return cv2.resize(noise, (size, size), interpolation=cv2.INTER_CUBIC).clip(0, 1)


def plane_view(x: float, tex: np.ndarray, w: int = 80, h: int = 60, alpha: bool = False, flat: bool = False) -> View:
    """A camera at (x, 0, 0) looking down +z at the plane z = PLANE_Z, its image rendered exactly."""
    import cv2

    cam = Camera(R=np.eye(3), t=-np.array([x, 0.0, 0.0]), fx=70.0, fy=70.0, cx=w / 2, cy=h / 2, width=w, height=h,
                 name=f"cam{x:+.2f}", near=2.0, far=20.0)
    v, u = np.meshgrid(np.arange(h) + 0.5, np.arange(w) + 0.5, indexing="ij")
    wx = x + PLANE_Z * (u - cam.cx) / cam.fx
    wy = PLANE_Z * (v - cam.cy) / cam.fy
    size = tex.shape[0]
    mx = ((wx + 4.0) / 8.0 * size - 0.5).astype(np.float32)  # world [-4, 4] -> texture pixels
    my = ((wy + 4.0) / 8.0 * size - 0.5).astype(np.float32)
    img = cv2.remap(tex, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    if flat:
        img = np.full_like(img, 0.4)
    if alpha:
        a = np.zeros((h, w, 1), np.float32)
        a[:, : w // 2] = 1.0  # left half is the object, right half background
        img = np.concatenate([img, a], axis=2)
    return View(camera=cam, image_path=None, loader=lambda img=img: img)


def test_plane_sweep_recovers_a_textured_plane():
    tex = texture()
    views = [plane_view(x, tex) for x in (-0.4, 0.0, 0.4)]
    logs: list[str] = []
    dense = dense_points(views, config=MVSConfig(num_depths=64), log=logs.append)
    assert dense.method == "mvs" and len(dense.points) > 0.5 * 3 * 80 * 60
    z = dense.points[:, 2]
    assert np.isfinite(dense.points).all() and (dense.colors >= 0).all() and (dense.colors <= 1).all()
    assert np.median(np.abs(z - PLANE_Z) / PLANE_Z) < 0.005 and np.percentile(np.abs(z - PLANE_Z), 95) < 0.1
    assert dense.stats["views"][0]["consistent"] <= dense.stats["views"][0]["matched"]
    assert any("3 training views" in m for m in logs)


def test_rgba_background_gives_no_points():
    tex = texture(seed=1)
    views = [plane_view(x, tex, alpha=True) for x in (-0.4, 0.0, 0.4)]
    dense = dense_points(views, config=MVSConfig(num_depths=64), log=lambda _m: None)
    # every point comes from a left-half (alpha 1) pixel of some view: world x < the rightmost camera's x
    assert len(dense.points) > 0 and dense.points[:, 0].max() < 0.4 + 1e-3


def test_textureless_views_fall_back_to_frustum_points():
    views = [plane_view(x, texture(), flat=True) for x in (-0.4, 0.0, 0.4)]
    cfg = MVSConfig(num_depths=16, fallback_points=3000, min_points=100)
    dense = dense_points(views, config=cfg, seed=3, log=lambda _m: None)
    assert dense.method == "fallback" and len(dense.points) == 3000 and "frustums" in dense.reason
    for view in views:  # every point lies between near and far of the view it was drawn for: check depth range
        z = view.camera.to_camera(dense.points)[:, 2]
        assert (z > 2.0 - 1e-3).all() and (z < 20.0 + 0.5).all()
    assert np.allclose(dense.colors, 0.4, atol=1e-5)
    again = dense_points(views, config=cfg, seed=3, log=lambda _m: None)
    assert np.array_equal(again.points, dense.points)  # seeded


def test_dense_initial_model_gives_gaussians_and_init_info():
    tex = texture(seed=2)
    views = [plane_view(x, tex) for x in (-0.4, 0.0, 0.4)]
    scene = Scene(views=views, splits={"train": [0, 1, 2], "test": []}, near=2.0, far=20.0)
    model, info = dense_initial_model(scene, scene.train, sh_degree=1, use_sfm=False,
                                      config=MVSConfig(num_depths=48, max_points=2000), log=lambda _m: None)
    assert info.method == "mvs" and model.num_gaussians == info.num_points == 2000


def test_sweep_budget_shrinks_the_working_size():
    tex = texture()
    few = [plane_view(x, tex, w=400, h=400) for x in (-0.4, 0.4)]
    many = [plane_view(x, tex, w=400, h=400) for x in np.linspace(-0.4, 0.4, 8)]
    assert working_side(few, MVSConfig()) == 256
    side = working_side(many, MVSConfig())
    assert side < 256 and 8 * 3 * 96 * side * side <= 1.0e8 * 1.01


def test_bad_config_is_refused():
    from gsgs_engine import GsgsError

    with pytest.raises(GsgsError, match="odd window"):
        MVSConfig(window=4).validate()


def test_train_and_export_starts_from_the_dense_model_with_init_mvs(tmp_path, monkeypatch):
    import gsgs_engine.init.mvs as mvs
    from gsgs_engine.reconstruct import train_and_export
    from gsgs_engine.train.trainer import TrainConfig
    from test_trainer import make_scene

    config = TrainConfig(iters=3, sh_degree=0, init="mvs", backend="auto", checkpoint_every=0, mvs_max_side=32)
    sizes = []
    real = mvs.dense_points
    monkeypatch.setattr(mvs, "dense_points", lambda *a, **k: sizes.append(k["config"].max_side) or real(*a, **k))
    metrics = train_and_export(make_scene(n_train=3, n_test=1), config, tmp_path / "out", None)
    assert metrics["init"]["method"].startswith("mvs") and metrics["iterations"] == 3
    assert metrics["plan"]["init"] == metrics["init"]
    assert sizes == [32]  # the sweep ran at the configured working size
    # the stereo and the initial Gaussians are part of the run's clock (the benchmarks' total seconds)
    assert metrics["phase_seconds"]["init"] > 0


def test_box_mean_matches_the_separable_pools_and_keeps_a_nan_in_its_window():
    import torch

    from gsgs_engine.init.mvs import _box, _box_pools as pools

    x = torch.rand(3, 4, 37, 29, generator=torch.Generator().manual_seed(0))
    for window in (3, 7, 41):  # 41: wider than the image, every pixel's window replicates the borders
        assert torch.allclose(_box(x, window), pools(x, window), atol=2e-6, rtol=0)
        assert torch.allclose(_box(x.double(), window), pools(x.double(), window), atol=1e-12, rtol=0)
    bad = x.clone()
    bad[0, 0, 10, 10] = float("nan")
    out = _box(bad, 7)
    assert int(torch.isnan(out).sum()) == 49  # only the 7 x 7 windows that hold it
    assert torch.equal(torch.isnan(out), torch.isnan(pools(bad, 7)))


def test_frustum_points_do_not_depend_on_the_thread_count():
    """A pixel drawn several times takes its last draw's depth on any number of threads: an indexed write of different
    depths to one pixel raced on two threads, and the fallback's points (an inward rig's whole initialisation when
    its views barely match) differed from run to run."""
    import torch

    views = [plane_view(x, texture(), flat=True) for x in (-0.4, 0.0, 0.4)]
    cfg = MVSConfig(num_depths=4, fallback_points=200_000, min_points=100)  # ~14 draws of every pixel
    threads = torch.get_num_threads()
    try:
        runs = []
        for n in (1, 2, 2, 2):
            torch.set_num_threads(n)
            runs.append(dense_points(views, config=cfg, seed=0, log=lambda _m: None).points)
    finally:
        torch.set_num_threads(threads)
    for other in runs[1:]:
        assert np.array_equal(other, runs[0])
    # every draw of a pixel lies at one depth: as many distinct points as pixels drawn (80 x 60 per view at most)
    assert len(np.unique(runs[0], axis=0)) <= 3 * 80 * 60


def test_the_fallback_tops_up_in_proportion_to_what_the_stereo_missed():
    """No cliff at min_points: a sweep that keeps half the minimum gets half the frustum points, one just under it a
    few, one at or above it none (all of them were added below the minimum, none above: frames of one capture with
    1,9xx and 2,0xx stereo points trained models 3 dB apart)."""
    from gsgs_engine.init.mvs import fallback_count

    cfg = MVSConfig(min_points=2000, fallback_points=20_000)
    assert [fallback_count(n, cfg) for n in (0, 1000, 1990, 2000, 5000)] == [20_000, 10_000, 100, 0, 0]
    tex = texture(seed=2)
    views = [plane_view(x, tex) for x in (-0.4, 0.0, 0.4)]
    stereo = dense_points(views, config=MVSConfig(num_depths=48, min_points=0), log=lambda _m: None)
    n = len(stereo.points)
    assert stereo.method == "mvs" and n > 100
    topped = dense_points(views, config=MVSConfig(num_depths=48, min_points=2 * n, fallback_points=3000),
                          log=lambda _m: None)
    assert topped.method == "mvs+fallback" and len(topped.points) == n + 1500
    assert np.array_equal(topped.points[:n], stereo.points)
