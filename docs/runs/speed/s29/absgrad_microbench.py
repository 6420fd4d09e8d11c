"""The compiled backward with and without AbsGS's statistic (session 29): forward + backward of the rasteriser alone,
on a trained model's projected Gaussians when a PLY is given, else the rasterizer benchmark's random scene.

    OMP_NUM_THREADS=2 python docs/runs/speed/s29/absgrad_microbench.py [--ply result/model.ply --job JOB_DIR]

Alternates the two (absgrad off / on), best of --repeats after a warm-up, prints a table (milliseconds)."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4]))

from gsgs_engine.render import cpu_backend  # noqa: E402
from tests.test_render_cpu import random_scene  # noqa: E402


def one(scene, absgrad: bool) -> float:
    x = {k: (v.clone().requires_grad_(True) if isinstance(v, torch.Tensor) and v.is_floating_point() else v)
         for k, v in scene.items()}
    t0 = time.perf_counter()
    color, depth, alpha = cpu_backend.rasterize_cpu(**x, absgrad=absgrad)
    (color.sum() + alpha.sum()).backward()
    return (time.perf_counter() - t0) * 1e3


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--sizes", default="50000")
    p.add_argument("--resolutions", default="200,400")
    p.add_argument("--repeats", type=int, default=9)
    args = p.parse_args()
    print(f"threads {torch.get_num_threads()}")
    print("| Gaussians | image | absgrad off, ms | absgrad on, ms | on / off |")
    print("|---|---|---|---|---|")
    for n in map(int, args.sizes.split(",")):
        for res in map(int, args.resolutions.split(",")):
            scene = random_scene(seed=7, n=n, width=res, height=res, spread=3.0 * res / 200)
            one(scene, False), one(scene, True)
            best = {False: float("inf"), True: float("inf")}
            for _ in range(args.repeats):
                for flag in (False, True):
                    best[flag] = min(best[flag], one(scene, flag))
            print(f"| {n} | {res}x{res} | {best[False]:.1f} | {best[True]:.1f} | {best[True] / best[False]:.3f} |")


if __name__ == "__main__":
    main()
