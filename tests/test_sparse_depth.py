"""The weights-free depth source: sparse SfM points densified with an image-guided filter."""

import numpy as np
import torch

from gsgs_engine.cameras import Camera
from gsgs_engine.priors.sparse_depth import SparseDepthSource, project_sparse_depth


def _camera(w=40, h=30):
    return Camera(R=np.eye(3), t=np.zeros(3), fx=30.0, fy=30.0, cx=w / 2, cy=h / 2, width=w, height=h)


def test_projection_keeps_the_nearest_point_per_pixel():
    cam = _camera()
    pts = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 5.0], [0.0, 0.0, -1.0], [100.0, 0.0, 1.0]])
    d = project_sparse_depth(cam, pts)
    assert d[15, 20] == 2.0 and np.count_nonzero(d) == 1


def test_a_slanted_plane_is_densified_close_to_its_inverse_depth():
    cam = _camera()
    rng = np.random.default_rng(0)
    uv = rng.uniform([0, 0], [40, 30], size=(150, 2))
    z = 3.0 + 0.05 * uv[:, 0]  # depth grows to the right
    pts = np.stack([(uv[:, 0] - 20) / 30 * z, (uv[:, 1] - 15) / 30 * z, z], axis=1)
    image = np.full((30, 40, 3), 0.5, np.float32)
    inv, valid = SparseDepthSource(pts).estimate(cam, image)
    truth = 1.0 / (3.0 + 0.05 * (np.arange(40) + 0.5))
    assert valid.float().mean() > 0.9 and torch.isfinite(inv).all()
    err = np.abs(inv.numpy() - truth[None, :])[valid.numpy()]
    assert err.mean() < 0.01 * truth.mean() * 10  # within a few percent of the inverse depth


def test_no_points_gives_an_empty_mask_not_nan():
    inv, valid = SparseDepthSource(np.zeros((0, 3))).estimate(_camera(), np.zeros((30, 40, 3), np.float32))
    assert not valid.any() and torch.isfinite(inv).all()


def test_a_point_density_below_one_percent_still_supports_the_pixels_between_points():
    """LLFF-like density (1 point in ~140 pixels): the image is covered, not rejected."""
    cam = _camera(w=200, h=150)
    rng = np.random.default_rng(1)
    uv = rng.uniform([0, 0], [200, 150], size=(210, 2))
    z = np.full(len(uv), 4.0)
    pts = np.stack([(uv[:, 0] - 100) / 30 * z, (uv[:, 1] - 75) / 30 * z, z], axis=1)
    inv, valid = SparseDepthSource(pts).estimate(cam, np.full((150, 200, 3), 0.5, np.float32))
    assert valid.float().mean() > 0.8
    assert np.allclose(inv.numpy()[valid.numpy()], 0.25, rtol=0.02)
    lone = SparseDepthSource(pts[:1]).estimate(cam, np.full((150, 200, 3), 0.5, np.float32))[1]
    assert 0 < lone.float().mean() < 0.05  # one point supports only its own neighbourhood
