"""The weights-free generator: exact for a surface every photo sees, honest about holes."""

import numpy as np
import torch

from gsgs_engine.cameras import Camera, look_at
from gsgs_engine.priors.warp_inpaint import (TrainingPhoto, fill_empty_depth, inpaint, inpaint_all, surface_depth,
                                             warp_inpaint, warp_photos)


def _cam(eye, w=48, h=40, f=50.0):
    R, t = look_at(np.asarray(eye, float), np.array([0.0, 0.0, 0.0]), up=(0.0, -1.0, 0.0))
    return Camera(R=R, t=t, fx=f, fy=f, cx=w / 2, cy=h / 2, width=w, height=h)


def _plane_view(cam, texture):
    """Exact image and depth of the textured plane z = 0 (colour = texture(x, y)) seen by `cam`."""
    v, u = torch.meshgrid(torch.arange(cam.height, dtype=torch.float64) + 0.5,
                          torch.arange(cam.width, dtype=torch.float64) + 0.5, indexing="ij")
    d_cam = torch.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, torch.ones_like(u)], -1)
    d_world = d_cam @ torch.as_tensor(cam.R)
    c = torch.as_tensor(cam.center)
    s = -c[2] / d_world[..., 2]  # ray parameter to z = 0
    pts = c + s[..., None] * d_world
    depth = s  # d_cam has unit z, so the ray parameter is the z-depth
    return texture(pts[..., 0], pts[..., 1]), depth


def _texture(x, y):
    return torch.stack([0.5 + 0.4 * torch.sin(3 * x), 0.5 + 0.4 * torch.cos(2 * y), 0.5 + 0.2 * torch.sin(x + y)], -1)


def test_a_plane_seen_by_all_photos_is_reproduced():
    train = [_cam([0.6, 0.1, -4.0]), _cam([-0.5, -0.2, -4.2])]
    pseudo = _cam([0.05, 0.0, -4.1])
    photos = []
    for cam in train:
        img, depth = _plane_view(cam, _texture)
        photos.append(TrainingPhoto(cam, img, depth))
    truth, depth = _plane_view(pseudo, _texture)
    alpha = torch.ones_like(depth)
    blurry_render = torch.full_like(truth, 0.5)
    image, stats = warp_inpaint(pseudo, blurry_render, depth * alpha, alpha, photos)
    assert stats["covered"] == 1.0 and stats["warped"] > 0.95
    err = (image - truth).abs().mean().item()
    assert err < 0.01, err  # the warped photos, not the blurry render
    assert (blurry_render - truth).abs().mean().item() > 0.05


def test_empty_pixels_keep_the_render_and_disocclusions_are_inpainted():
    cam = _cam([0.0, 0.0, -4.0], w=32, h=24)
    img, depth = _plane_view(cam, _texture)
    photo = TrainingPhoto(cam, img, depth)
    alpha = torch.ones_like(depth)
    alpha[:, :4] = 0.0  # the render is empty here: keep the render's background
    render = torch.ones_like(img)
    far_photo = TrainingPhoto(cam, img, depth * 3.0)  # disagrees everywhere: occluded, nothing copied
    image, stats = warp_inpaint(cam, render, depth * alpha, alpha, [photo])
    assert torch.all(image[:, :4] == 1.0)
    assert torch.allclose(image[:, 4:], img[:, 4:], atol=1e-6)
    occluded, ostats = warp_inpaint(cam, render, depth * alpha, alpha, [far_photo])
    assert ostats["warped"] == 0.0 and ostats["inpainted"] == 1.0
    assert torch.isfinite(occluded).all()


def test_inpaint_fills_only_holes_and_surface_depth_is_safe():
    img = torch.rand(16, 16, 3)
    holes = torch.zeros(16, 16, dtype=torch.bool)
    holes[6:9, 6:9] = True
    out = inpaint(img, holes)
    assert torch.equal(out[~holes], img[~holes]) and not torch.equal(out[holes], img[holes])
    z = surface_depth(torch.tensor([[0.0, 1.0]]), torch.tensor([[0.0, 0.5 + 1e-3]]))
    assert z[0, 0] == 0 and torch.isfinite(z).all()


def test_fill_empty_inpaints_what_the_render_leaves_empty():
    cam = _cam([0.0, 0.0, -4.0], w=32, h=24)
    img, depth = _plane_view(cam, _texture)
    alpha = torch.ones_like(depth)
    alpha[:, -6:] = 0.0  # unseen content at the right edge (a photo scene has no background there)
    render = torch.ones_like(img)
    image, stats = warp_inpaint(cam, render, depth * alpha, alpha, [TrainingPhoto(cam, img, depth)], fill_empty=True)
    assert stats["empty_filled"] == 6 / 32
    # filled from the content beside it, not left at the render's white
    assert (image[:, -6:] - 1.0).abs().mean() > 0.1
    assert (image[:, -6:] - img[:, -7:-6]).abs().mean() < (1.0 - img[:, -7:-6]).abs().mean()


def test_a_round_inpainted_on_threads_equals_each_view_alone():
    g = torch.Generator().manual_seed(3)
    images = [torch.rand(40, 56, 3, generator=g) for _ in range(5)]
    holes = [torch.rand(40, 56, generator=g) < f for f in (0.0, 0.1, 0.3, 0.6, 0.9)]
    alone = [inpaint(img, h).clamp(0, 1) for img, h in zip(images, holes)]
    for workers in (1, 2, 4):
        together = inpaint_all(images, holes, workers=workers)
        assert all(torch.equal(a, b) for a, b in zip(alone, together)), workers
    # warp_inpaint is warp_photos then the inpainting of what it leaves
    cam = _cam([0.0, 0.0, -4.0], w=32, h=24)
    img, depth = _plane_view(cam, _texture)
    alpha = torch.ones_like(depth)
    alpha[:, -6:] = 0.0
    render = torch.ones_like(img)
    photos = [TrainingPhoto(cam, img, depth * 3.0)]  # occluded everywhere: every covered pixel is a hole
    whole, stats = warp_inpaint(cam, render, depth * alpha, alpha, photos, fill_empty=True)
    warped, to_fill, stats2 = warp_photos(cam, render, depth * alpha, alpha, photos, fill_empty=True)
    assert stats == stats2 and bool(to_fill.all())
    assert torch.equal(whole, inpaint_all([warped], [to_fill], workers=2)[0])


def test_fill_empty_depth_extends_the_surface_and_keeps_known_depth():
    z = torch.full((20, 30), 4.0)
    z[:, 20:] = 0.0
    z[:10, :20] = 6.0
    filled = fill_empty_depth(z)
    assert torch.equal(filled[:, :20], z[:, :20])
    assert torch.isfinite(filled).all() and (filled[:, 20:] >= 4.0).all() and (filled[:, 20:] <= 6.0).all()
    assert filled[:5, 25].mean() > filled[-5:, 25].mean()  # nearer the 6.0 rows, deeper
    assert torch.equal(fill_empty_depth(torch.zeros(4, 4)), torch.zeros(4, 4))  # nothing to fill from


def test_visibility_tolerance_decides_which_photo_pixels_count_and_reaches_the_prior_settings():
    from gsgs_engine.priors.config import PriorConfig, prior_config_from_settings, resolve_prior_plan

    cam = _cam([0.0, 0.0, -4.0], w=32, h=24)
    img, depth = _plane_view(cam, _texture)
    alpha = torch.ones_like(depth)
    off_by_8 = TrainingPhoto(cam, img, depth * 1.08)  # the photo's rendered depth is 8 % off
    _, strict = warp_inpaint(cam, torch.ones_like(img), depth, alpha, [off_by_8], rel_tolerance=0.05)
    _, loose = warp_inpaint(cam, torch.ones_like(img), depth, alpha, [off_by_8], rel_tolerance=0.1)
    assert strict["warped"] == 0.0 and loose["warped"] == 1.0
    cfg = prior_config_from_settings({"prior": "warp", "prior_settings": {"warp_tolerance": 0.1}})
    assert cfg.warp_tolerance == 0.1 and resolve_prior_plan(cfg, 3)["warp_tolerance"] == 0.1
    assert PriorConfig().warp_tolerance == 0.05
