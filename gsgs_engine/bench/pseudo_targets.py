"""`gsgs bench pseudo-targets`: are warp-inpaint pseudo targets better than the render, where the truth is known?

    gsgs bench pseudo-targets DATA RESULT/point_cloud.ply [--train-views N] [--max-test 10]

Loads a trained model, renders the training views (their depth is what the warp uses), then
treats held-out test views as pseudo views: for each it prints the test PSNR of the render and
of the warp-inpaint target built from the training photos, as the prior would build it. A
prior can only teach what its targets get right: where the target scores below the render,
pseudo supervision pulls the model away from the truth. A bad input exits 2 with one
`gsgs: error:` line.
"""

from __future__ import annotations

import argparse


def _psnr(a, b) -> float:
    import torch

    return float(-10.0 * torch.log10(((a - b) ** 2).mean().clamp_min(1e-12)))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", help="the scene the result was trained on")
    parser.add_argument("ply", help="the trained result's point_cloud.ply")
    parser.add_argument("--train-views", type=int, default=None, help="as given to gsgs train")
    parser.add_argument("--max-test", type=int, default=10, help="test views used, spread over the split")
    parser.add_argument("--backend", default="auto")


def run(args: argparse.Namespace) -> int:
    """Exit 0 with the table; a bad input raises GsgsError (gsgs prints one `gsgs: error:` line, exits 2)."""
    from gsgs_engine import GsgsError

    if args.train_views is not None and args.train_views < 1:
        raise GsgsError(f"--train-views must be at least 1 (got {args.train_views})")
    if args.max_test < 1:
        raise GsgsError(f"--max-test must be at least 1 (got {args.max_test})")
    import numpy as np
    import torch

    from gsgs_engine.gaussians import GaussianModel
    from gsgs_engine.io import load_scene
    from gsgs_engine.io.ply import read_gaussian_ply
    from gsgs_engine.io.world_scale import ply_to_internal
    from gsgs_engine.priors.warp_inpaint import TrainingPhoto, surface_depth, warp_inpaint
    from gsgs_engine.render import render

    scene = load_scene(args.data, train_views=args.train_views)
    splats = read_gaussian_ply(args.ply)  # a NaN / Inf value is an error naming the file
    if len(splats) == 0:
        raise GsgsError(f"{args.ply}: the PLY holds no Gaussians; pass a trained result")
    if not scene.test:
        raise GsgsError(f"{args.data}: the scene has no test views to measure on")
    model = GaussianModel.from_ply(ply_to_internal(splats, scene.world_scale))
    background = torch.as_tensor(scene.background, dtype=torch.float32)
    degree = model.max_sh_degree

    @torch.no_grad()
    def render_at(camera):
        return render(model.means, model.quats, model.scales, model.opacities, model.sh(degree), camera,
                      sh_degree=degree, background=background, backend=args.backend)

    def image_of(view) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(view.image(), dtype=np.float32))

    photos = []
    for view in scene.train:
        out = render_at(view.camera)
        photos.append(TrainingPhoto(view.camera, image_of(view), surface_depth(out.depth, out.alpha)))
    test = scene.test
    picks = np.unique(np.round(np.linspace(0, len(test) - 1, min(args.max_test, len(test)))).astype(int))
    fill_empty = not scene.has_alpha
    rows = []
    print(f"{'view':24s} {'render dB':>10s} {'target dB':>10s}")
    for i in picks:
        view = test[int(i)]
        truth = image_of(view)
        out = render_at(view.camera)
        target, _ = warp_inpaint(view.camera, out.color, out.depth, out.alpha, photos, fill_empty=fill_empty)
        rows.append((_psnr(out.color, truth), _psnr(target, truth)))
        print(f"{view.name:24s} {rows[-1][0]:10.2f} {rows[-1][1]:10.2f}")
    mean = np.mean(rows, axis=0)
    print(f"{'mean':24s} {mean[0]:10.2f} {mean[1]:10.2f}")
    if not np.isfinite(mean).all():
        raise GsgsError("a PSNR is not finite (the renders or targets hold NaN); the result is damaged")
    return 0
