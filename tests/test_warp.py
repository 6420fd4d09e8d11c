"""Warping between posed views: identity, and a fronto-parallel plane against its analytic homography."""

import numpy as np
import pytest
import torch

from gsgs_engine.cameras import Camera
from gsgs_engine.priors.warp import backward_warp, forward_warp, unproject


def _rot_y(deg):
    a = np.deg2rad(deg)
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])


def _camera(R=np.eye(3), t=np.zeros(3), w=40, h=30, f=35.0, cx=None, cy=None):
    return Camera(R=R, t=t, fx=f, fy=f, cx=w / 2 if cx is None else cx, cy=h / 2 if cy is None else cy, width=w, height=h)


def _coord_image(cam):
    v, u = torch.meshgrid(torch.arange(cam.height, dtype=torch.float64) + 0.5,
                          torch.arange(cam.width, dtype=torch.float64) + 0.5, indexing="ij")
    return torch.stack([u, v, torch.ones_like(u)], dim=-1)


def test_identity_pose_returns_the_image():
    cam = _camera(cx=18.3, cy=16.1)
    img = torch.rand(cam.height, cam.width, 3, dtype=torch.float64)
    depth = 2.0 + torch.rand(cam.height, cam.width, dtype=torch.float64)
    warped, wdepth, valid = forward_warp(img, depth, cam, cam)
    assert valid.all()
    assert torch.allclose(warped, img) and torch.allclose(wdepth, depth)
    back, bvalid = backward_warp(cam, depth, cam, img, depth)
    assert bvalid.all() and torch.allclose(back, img, atol=1e-9)


@pytest.mark.parametrize("direction", ["forward", "backward"])
def test_fronto_parallel_plane_follows_the_homography(direction):
    # Source camera at the origin looks at the plane z = 4; the target is rotated 5 degrees
    # and shifted. For a plane n.X = d in the source frame, target ~ K2 (R - t n^T / d) K1^-1 source.
    src = _camera(w=48, h=36, f=40.0)
    R2, t2 = _rot_y(5.0), np.array([0.3, -0.1, 0.2])
    dst = _camera(R=R2, t=t2, w=52, h=34, f=44.0, cx=27.0, cy=16.0)
    d = 4.0
    n = np.array([0.0, 0.0, 1.0])
    H = dst.K @ (R2 + np.outer(t2, n) / d) @ np.linalg.inv(src.K)
    src_depth = torch.full((src.height, src.width), d, dtype=torch.float64)
    coords = _coord_image(src)
    if direction == "forward":
        warped, _, valid = forward_warp(coords, src_depth, src, dst)
        ys, xs = torch.nonzero(valid, as_tuple=True)
        assert len(ys) > 0.5 * dst.width * dst.height
        src_uv = warped[ys, xs, :2].numpy()
        mapped = (H @ np.c_[src_uv, np.ones(len(src_uv))].T).T
        mapped = mapped[:, :2] / mapped[:, 2:]
        # The source point lands inside the destination pixel it was splatted to.
        assert np.all(np.floor(mapped[:, 0]) == xs.numpy()) and np.all(np.floor(mapped[:, 1]) == ys.numpy())
    else:
        # Depth of the plane seen from the destination camera, per pixel.
        pts = unproject(dst, torch.ones(dst.height, dst.width, dtype=torch.float64))
        c2 = torch.as_tensor(dst.center)
        rays = pts - c2
        s = (d - c2[2]) / rays[..., 2]
        dst_depth = s  # unit-depth rays scaled to hit z = d
        sampled, valid = backward_warp(dst, dst_depth, src, coords, src_depth)
        ys, xs = torch.nonzero(valid, as_tuple=True)
        assert len(ys) > 0.5 * dst.width * dst.height
        dst_uv = np.c_[xs.numpy() + 0.5, ys.numpy() + 0.5, np.ones(len(xs))]
        expect = (np.linalg.inv(H) @ dst_uv.T).T
        expect = expect[:, :2] / expect[:, 2:]
        inner = (expect[:, 0] > 0.5) & (expect[:, 0] < src.width - 0.5) & (expect[:, 1] > 0.5) & (expect[:, 1] < src.height - 0.5)
        assert np.allclose(sampled[ys, xs, :2].numpy()[inner], expect[inner], atol=1e-6)


def test_z_buffer_keeps_the_nearer_surface_and_occlusion_is_rejected():
    cam = _camera(w=20, h=20, f=20.0)
    img = torch.zeros(20, 20, 3, dtype=torch.float64)
    img[:, :10, 0] = 1.0  # near half red
    img[:, 10:, 1] = 1.0  # far half green
    depth = torch.full((20, 20), 5.0, dtype=torch.float64)
    depth[:, :10] = 2.0
    # A camera moved right sees the near half slide over the far half: overlapping pixels show red.
    side = _camera(t=np.array([-0.6, 0.0, 0.0]), w=20, h=20, f=20.0)
    warped, wdepth, valid = forward_warp(img, depth, cam, side)
    both = valid & (wdepth < 3.0)
    assert both.any() and torch.all(warped[both][:, 0] == 1.0)
    # Backward: the far surface behind the near one is not copied from a view that cannot see it.
    far_only = torch.full((20, 20), 5.0, dtype=torch.float64)
    _, bvalid = backward_warp(side, far_only, cam, img, depth)
    assert not bvalid.all()


def test_points_behind_the_target_camera_are_invalid():
    cam = _camera(w=16, h=12, f=16.0)
    behind = _camera(R=_rot_y(180.0), t=np.array([0.0, 0.0, -1.0]), w=16, h=12, f=16.0)
    depth = torch.full((12, 16), 3.0, dtype=torch.float64)
    img = torch.rand(12, 16, 3, dtype=torch.float64)
    _, _, valid = forward_warp(img, depth, cam, behind)
    assert not valid.any()
