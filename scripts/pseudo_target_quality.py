"""Are warp-inpaint pseudo targets better than the render? Checked where the truth is known.

    python scripts/pseudo_target_quality.py DATA RESULT/point_cloud.ply [--train-views N] [--max-test 10]

Loads a trained model, renders the training views (their depth is what the warp uses), then
treats held-out test views as pseudo views: for each it prints the test PSNR of the render and
of the warp-inpaint target built from the training photos, as the prior would build it. A
prior can only teach what its targets get right: where the target scores below the render,
pseudo supervision pulls the model away from the truth.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def _psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(-10.0 * torch.log10(((a - b) ** 2).mean().clamp_min(1e-12)))


def main(argv: list[str] | None = None) -> int:
    """Exit 0 with the table; 2 with one `pseudo_target_quality: error:` line for a bad input."""
    from gsgs_engine import GsgsError

    try:
        return _run(argv)
    except GsgsError as exc:
        print(f"pseudo_target_quality: error: {exc}", file=sys.stderr)
        return 2


def _run(argv: list[str] | None) -> int:
    from gsgs_engine import GsgsError
    from gsgs_engine.gaussians import GaussianModel
    from gsgs_engine.io import load_scene
    from gsgs_engine.io.ply import read_gaussian_ply
    from gsgs_engine.priors.warp_inpaint import TrainingPhoto, surface_depth, warp_inpaint
    from gsgs_engine.render import render

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("data")
    parser.add_argument("ply")
    parser.add_argument("--train-views", type=int, default=None, help="as given to gsgs train")
    parser.add_argument("--max-test", type=int, default=10, help="test views used, spread over the split")
    parser.add_argument("--backend", default="auto")
    args = parser.parse_args(argv)
    if args.train_views is not None and args.train_views < 1:
        raise GsgsError(f"--train-views must be at least 1 (got {args.train_views})")
    if args.max_test < 1:
        raise GsgsError(f"--max-test must be at least 1 (got {args.max_test})")
    from gsgs_engine.io.world_scale import ply_to_internal

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


if __name__ == "__main__":
    raise SystemExit(main())
