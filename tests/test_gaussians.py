"""Gaussian model: initialisation, activations, SH slicing, PLY round trip, random-init bounds."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from gsgs_engine import GsgsError
from gsgs_engine.cameras import Camera
from gsgs_engine.gaussians import (GaussianModel, knn_mean_sq_dist, rgb_to_sh_dc, scene_bounds_from_cameras,
                                   sh_dc_to_rgb)


def test_knn_matches_brute_force_across_chunks():
    pts = torch.from_numpy(np.random.default_rng(0).normal(size=(300, 3)).astype(np.float32))
    d2 = torch.cdist(pts, pts).square()
    d2.fill_diagonal_(float("inf"))
    expected = torch.topk(d2, 3, largest=False).values.mean(1)
    got = knn_mean_sq_dist(pts, k=3, chunk=64)  # several chunks, last one partial
    assert torch.allclose(got, expected, rtol=1e-4, atol=1e-6)


def test_knn_by_kd_leaves_is_exact_with_clusters_duplicates_and_outliers():
    rng = np.random.default_rng(1)
    flat = rng.normal(size=(500, 3)) * [1.0, 2.0, 0.05]  # a surface-like sheet
    cluster = rng.normal(size=(150, 3)) * 0.01 + [3.0, 0.0, 0.0]
    outliers = rng.uniform(-50, 50, size=(8, 3))
    dupes = np.repeat(flat[:3], 5, axis=0)  # coincident points: their neighbours are at distance 0
    pts = torch.from_numpy(np.concatenate([flat, cluster, outliers, dupes]).astype(np.float32))
    brute = knn_mean_sq_dist(pts, k=3, leaf=10 ** 9)
    for leaf in (8, 16, 64):  # many leaves: the leaf search runs
        # the same neighbours; cdist rounds a pair slightly differently in a differently shaped block
        assert torch.allclose(knn_mean_sq_dist(pts, k=3, leaf=leaf), brute, rtol=1e-4, atol=1e-5), leaf
    assert (brute[-15:] == 0).all() and (brute[650:658] > 10).all()


def test_from_points_sizes_by_neighbours_and_sets_colours():
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [10, 10, 10]], np.float32)
    cols = np.array([[1, 0, 0]] * 5, np.float32)
    m = GaussianModel.from_points(pts, cols, max_sh_degree=2)
    assert m.num_gaussians == 5
    assert torch.allclose(m.scales[0], torch.ones(3))  # three neighbours at distance 1
    assert float(m.scales[4, 0].detach()) > 10  # the outlier gets a big Gaussian
    assert torch.allclose(m.opacities, torch.full((5,), 0.1), atol=1e-6)
    assert torch.allclose(sh_dc_to_rgb(m.params["sh_dc"][:, 0]), torch.tensor(cols), atol=1e-6)
    assert m.params["sh_rest"].shape == (5, 8, 3)
    assert torch.allclose(m.quats, torch.tensor([[1.0, 0, 0, 0]] * 5))


def test_sh_slices_to_the_active_degree():
    m = GaussianModel.from_points(np.random.rand(10, 3), None, max_sh_degree=3)
    assert m.sh().shape == (10, 1, 3)
    m.raise_sh_degree()
    m.raise_sh_degree()
    assert m.active_sh_degree == 2 and m.sh().shape == (10, 9, 3)
    for _ in range(5):
        m.raise_sh_degree()
    assert m.active_sh_degree == 3 and m.sh().shape == (10, 16, 3)


def test_bad_shapes_and_degrees_are_refused():
    with pytest.raises(GsgsError, match="SH degree"):
        GaussianModel.from_points(np.zeros((3, 3)), None, max_sh_degree=4)
    with pytest.raises(GsgsError, match="empty"):
        GaussianModel.from_points(np.zeros((0, 3)), None, max_sh_degree=0)
    with pytest.raises(GsgsError, match="sh_rest"):
        GaussianModel(torch.zeros(2, 3), torch.zeros(2, 3), torch.zeros(2, 4), torch.zeros(2), torch.zeros(2, 1, 3),
                      torch.zeros(2, 2, 3), 1)


@pytest.mark.parametrize("degree", [0, 1, 3])
def test_ply_round_trip(tmp_path, degree):
    from gsgs_engine.io.ply import read_gaussian_ply, write_gaussian_ply

    g = torch.Generator().manual_seed(degree)
    n = 17
    m = GaussianModel(torch.randn(n, 3, generator=g), torch.randn(n, 3, generator=g), torch.randn(n, 4, generator=g),
                      torch.randn(n, generator=g), torch.randn(n, 1, 3, generator=g),
                      torch.randn(n, (degree + 1) ** 2 - 1, 3, generator=g), degree)
    write_gaussian_ply(tmp_path / "p.ply", m.to_ply())
    back = GaussianModel.from_ply(read_gaussian_ply(tmp_path / "p.ply"))
    assert back.max_sh_degree == degree and back.active_sh_degree == degree
    for name, value in m.params.items():
        assert torch.equal(back.params[name], value.detach()), name


def test_state_dict_round_trip_keeps_degrees():
    m = GaussianModel.from_points(np.random.rand(8, 3), None, max_sh_degree=3)
    m.raise_sh_degree()
    back = GaussianModel.from_state_dict(m.state_dict())
    assert back.active_sh_degree == 1 and back.max_sh_degree == 3
    assert all(torch.equal(back.params[k], v.detach()) for k, v in m.params.items())
    assert all(v.requires_grad and v.is_leaf for v in back.params.values())


def _look_at(eye, target=(0, 0, 0)):
    eye = np.asarray(eye, float)
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, [0, 0, 1.0])
    r /= np.linalg.norm(r)
    R = np.stack([r, np.cross(f, r), f])
    return Camera(R=R, t=-R @ eye, fx=50, fy=50, cx=16, cy=16, width=32, height=32)


def test_random_init_box_for_inward_cameras_is_centred_on_the_object():
    cams = [_look_at((4 * math.cos(a), 4 * math.sin(a), 1.0), target=(0.2, -0.1, 0.3))
            for a in np.linspace(0, 2 * math.pi, 6, endpoint=False)]
    lo, hi = scene_bounds_from_cameras(cams)
    assert np.allclose((lo + hi) / 2, [0.2, -0.1, 0.3], atol=1e-6)
    assert 1.0 < (hi - lo)[0] / 2 < 1.6  # ~ a third of the 4.1-unit camera distance
    m = GaussianModel.random_in_box(lo, hi, 500, 0, generator=torch.Generator().manual_seed(0))
    pts = m.means.detach().numpy()
    assert np.all(pts >= lo - 1e-6) and np.all(pts <= hi + 1e-6)


def test_random_init_box_for_forward_facing_cameras_lies_ahead():
    cams = [_look_at((x, -5.0, 0.0), target=(x, 0.0, 0.0)) for x in (-0.5, 0.0, 0.5)]
    lo, hi = scene_bounds_from_cameras(cams, near=1.0, far=9.0)
    centre = (lo + hi) / 2
    assert centre[1] == pytest.approx(0.0, abs=1e-6)  # 5 units ahead of the cameras at y = -5
    assert hi[1] - lo[1] > 8.0


def test_sh_dc_conversion_inverts():
    rgb = torch.rand(20, 3)
    assert torch.allclose(sh_dc_to_rgb(rgb_to_sh_dc(rgb)), rgb, atol=1e-6)
