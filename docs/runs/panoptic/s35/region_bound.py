"""Issue 31, session 35: how much a perfect dynamic region could add to a model's PSNR on the test cameras.

For each test view (camera x frame) of the bench's runs kept in docs/runs/panoptic/s34/, with the view's PSNR P,
its dynamic-region PSNR R and the region's share f of the view's pixels (gsgs_engine.bench.dynamic_region, the
bench's own definition, recomputed here from the test photos at the bench's half resolution):
    MSE = f MSE_region + (1 - f) MSE_rest,   so with the region exact:  MSE' = MSE - f MSE_region.
The mean over the views of -10 log10 MSE' is what the model would score with the same room (everything outside
the region) and no error in the region: the most that modelling the people can add to it.

    .venv/bin/python docs/runs/panoptic/s35/region_bound.py     (about 20 s; reads ../shared/data/panoptic_basketball)
"""
import json
import math
from pathlib import Path

import numpy as np

from gsgs_engine.bench.dynamic_region import region_masks
from gsgs_engine.io.panoptic import load_panoptic

HERE = Path(__file__).resolve().parent
S34 = HERE.parent / "s34"
DATA = HERE.parents[4] / "shared" / "data" / "panoptic_basketball"
if not DATA.is_dir():
    DATA = Path("/work/shared/data/panoptic_basketball")

# The test cameras and frames do not depend on the number of training cameras.
scene = load_panoptic(DATA, train_cameras=3, frames=list(range(10)), resolution_scale=0.5)
region_of, what = region_masks(scene.test)
share = {v.name: float(region_of(v).mean()) for v in scene.test}
print(f"{len(scene.test)} test views; region: {what}")
print(f"region's share of a test view's pixels: mean {np.mean(list(share.values())):.4f}, "
      f"min {min(share.values()):.4f}, max {max(share.values()):.4f}")


def room_psnr(model: dict) -> float:
    """Mean over the views of the PSNR outside the region: MSE_rest = (MSE - f MSE_region) / (1 - f)."""
    out = []
    for v in model["per_view"]:
        f, mse, mse_region = share[v["name"]], 10 ** (-v["psnr"] / 10), 10 ** (-v["psnr_region"] / 10)
        out.append(-10 * math.log10(max(mse - f * mse_region, 1e-12) / (1 - f)))
    return float(np.mean(out))


def with_exact_region(model: dict) -> tuple[float, float]:
    scored, bound = [], []
    for v in model["per_view"]:
        f, mse, mse_region = share[v["name"]], 10 ** (-v["psnr"] / 10), 10 ** (-v["psnr_region"] / 10)
        scored.append(v["psnr"])
        bound.append(-10 * math.log10(max(mse - f * mse_region, 1e-12)))
    return float(np.mean(scored)), float(np.mean(bound))


rooms = []
print("| cameras, seed | best static model | its PSNR | the same with an exact region | 4D PSNR | 4D with an exact region |")
print("|---|---|---|---|---|---|")
for cams in (3, 6, 9):
    for seed in (0, 1, 2):
        full = json.loads((S34 / f"full_c{cams}_s{seed}.json").read_text())
        pf100 = json.loads((S34 / f"pf100_c{cams}_s{seed}.json").read_text())
        static = {"per frame, 300 steps": full["static_per_frame"], "all frames": full["static_all"],
                  "per frame, 100 steps": pf100["static_per_frame"]}
        name, best = max(static.items(), key=lambda kv: kv[1]["psnr"])
        p, b = with_exact_region(best)
        p4, b4 = with_exact_region(full["4d"])
        print(f"| {cams}, seed {seed} | {name} | {p:.2f} | {b:.2f} (+{b - p:.2f}) | {p4:.2f} | {b4:.2f} (+{b4 - p4:.2f}) |")
        rooms.append((cams, seed, {"4D": full["4d"], **static}))

print()
print("PSNR outside the region (the room) / whole view / region, each model:")
print("| cameras, seed | 4D | static, all frames | static per frame, 300 steps | static per frame, 100 steps |")
print("|---|---|---|---|---|")
for cams, seed, models in rooms:
    cells = [f"{room_psnr(m):.2f} / {m['psnr']:.2f} / {m['psnr_region']:.2f}" for m in
             (models["4D"], models["all frames"], models["per frame, 300 steps"], models["per frame, 100 steps"])]
    print(f"| {cams}, seed {seed} | " + " | ".join(cells) + " |")
