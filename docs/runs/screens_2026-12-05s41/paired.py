"""Session 41 (docs/sparse_techniques.md "Session 41"): LLFF 3 views at 3000 steps, the long forward recipe (L3k)
against it with `clone_split` first (L3kcs), paired by seed over session 40's seeds 0-2 and this session's unseen 3-5;
and the seed-0 screens of this folder (absgrad, the half-size binocular view) against session 40's seed-0 cells.
python docs/runs/screens_2026-12-05s41/paired.py"""
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
FOLDERS = (HERE.parent / "screens_2026-12-05s40", HERE)
SCENES = ("flower", "horns")


def cell(tag, scene, seed):
    for folder in FOLDERS:
        f = folder / f"llff_llff_{scene}_{tag}_seed{seed}.json"
        if f.exists():
            return json.loads(f.read_text())
    return None


def mean(tag, seeds, key):
    return np.mean([cell(tag, s, k)[key] for k in seeds for s in SCENES])


for label, seeds in (("seeds 0-2", (0, 1, 2)), ("unseen seeds 3-5", (3, 4, 5)), ("seeds 0-5", tuple(range(6)))):
    per_seed = [np.mean([cell("L3kcs", s, k)["psnr"] - cell("L3k", s, k)["psnr"] for s in SCENES]) for k in seeds]
    higher = sum(cell("L3kcs", s, k)["psnr"] > cell("L3k", s, k)["psnr"] for k in seeds for s in SCENES)
    print(f"{label:17s} PSNR {mean('L3k', seeds, 'psnr'):.2f} -> {mean('L3kcs', seeds, 'psnr'):.2f}"
          f" (paired by seed {' / '.join(f'{d:+.2f}' for d in per_seed)}; {higher} of {2 * len(seeds)} cells higher)"
          f"  SSIM {mean('L3k', seeds, 'ssim'):.3f} -> {mean('L3kcs', seeds, 'ssim'):.3f}"
          f"  LPIPS {mean('L3k', seeds, 'lpips'):.3f} -> {mean('L3kcs', seeds, 'lpips'):.3f}")
for k in range(6):
    print(f"seed {k}: " + "; ".join(f"{s} {cell('L3k', s, k)['psnr']:.2f} -> {cell('L3kcs', s, k)['psnr']:.2f}"
                                    for s in SCENES))
for tag in ("L3k", "L3kcs", "L3kab", "L3kh"):
    got = [cell(tag, s, 0) for s in SCENES]
    if all(got):
        print(f"seed 0 {tag:6s} " + " / ".join(f"{m['psnr']:.2f}" for m in got)
              + f"  mean {np.mean([m['psnr'] for m in got]):.2f}  SSIM {np.mean([m['ssim'] for m in got]):.3f}"
              + f"  LPIPS {np.mean([m['lpips'] for m in got]):.3f}  train s {np.mean([m['train_seconds'] for m in got]):.0f}")
# absgrad first in the long forward recipe (L3kab), paired with L3k by seed over the seeds both have
both = [k for k in range(6) if all(cell(t, s, k) for t in ("L3k", "L3kab") for s in SCENES)]
for k in both:
    print(f"L3kab seed {k}: " + "; ".join(f"{s} {cell('L3k', s, k)['psnr']:.2f} -> {cell('L3kab', s, k)['psnr']:.2f}"
                                          for s in SCENES)
          + f"  train s {np.mean([cell('L3kab', s, k)['train_seconds'] for s in SCENES]):.0f}")
if both:
    print(f"L3kab seeds {','.join(map(str, both))}: PSNR {mean('L3k', both, 'psnr'):.2f} -> {mean('L3kab', both, 'psnr'):.2f}"
          f"  SSIM {mean('L3k', both, 'ssim'):.3f} -> {mean('L3kab', both, 'ssim'):.3f}"
          f"  LPIPS {mean('L3k', both, 'lpips'):.3f} -> {mean('L3kab', both, 'lpips'):.3f}")
