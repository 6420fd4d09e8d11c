"""Session 42 (docs/sparse_techniques.md "Session 42"): LLFF 3 views at 3000 steps, the long forward recipe (L3k)
against it with `absgrad` first (L3kab), paired by seed over sessions 40-41's seeds 0-2 and this session's unseen
3-5 (the L3k cells of seeds 3-5 are session 41's), and the LLFF screens of this folder against their references.
python docs/runs/screens_2026-12-05s42/paired.py"""
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).parent
FOLDERS = (HERE.parent / "screens_2026-12-05s40", HERE.parent / "screens_2026-12-05s41", HERE)
SCENES = ("flower", "horns")


def cell(tag, scene, seed):
    for folder in reversed(FOLDERS):  # this session's cell where there is one
        f = folder / f"llff_llff_{scene}_{tag}_seed{seed}.json"
        if f.exists():
            return json.loads(f.read_text())
    return None


def mean(tag, seeds, key):
    return np.mean([cell(tag, s, k)[key] for k in seeds for s in SCENES])


def compare(base, new, seeds_sets):
    for label, seeds in seeds_sets:
        if not all(cell(t, s, k) for t in (base, new) for s in SCENES for k in seeds):
            print(f"{new} {label}: cells missing")
            continue
        per_seed = [np.mean([cell(new, s, k)["psnr"] - cell(base, s, k)["psnr"] for s in SCENES]) for k in seeds]
        higher = sum(cell(new, s, k)["psnr"] > cell(base, s, k)["psnr"] for k in seeds for s in SCENES)
        se = (f", standard error {np.std(per_seed, ddof=1) / np.sqrt(len(per_seed)):.2f}" if len(per_seed) > 1
              else "")
        print(f"{new} {label:17s} PSNR {mean(base, seeds, 'psnr'):.2f} -> {mean(new, seeds, 'psnr'):.2f}"
              f" (paired by seed {' / '.join(f'{d:+.2f}' for d in per_seed)}{se};"
              f" {higher} of {2 * len(seeds)} cells higher)"
              f"  SSIM {mean(base, seeds, 'ssim'):.3f} -> {mean(new, seeds, 'ssim'):.3f}"
              f"  LPIPS {mean(base, seeds, 'lpips'):.3f} -> {mean(new, seeds, 'lpips'):.3f}"
              f"  train s {mean(base, seeds, 'train_seconds'):.0f} -> {mean(new, seeds, 'train_seconds'):.0f}")
    for k in sorted({k for _, seeds in seeds_sets for k in seeds}):
        if all(cell(t, s, k) for t in (base, new) for s in SCENES):
            print(f"  seed {k}: " + "; ".join(
                f"{s} {cell(base, s, k)['psnr']:.2f} -> {cell(new, s, k)['psnr']:.2f}"
                f" ({cell(base, s, k)['train_seconds']:.0f} -> {cell(new, s, k)['train_seconds']:.0f} s)" for s in SCENES))


compare("L3k", "L3kab", (("seeds 0-2", (0, 1, 2)), ("unseen seeds 3-5", (3, 4, 5)), ("seeds 0-5", tuple(range(6)))))
compare("L3kab", "L3kabh", (("seed 0", (0,)),))  # the half-size binocular view at 3000 steps
# at 1000 steps against the recipe's own cells (session 40's `planned`): the triangulation without domain-size
# pooling (seed 0) and the binocular view at full size with absgrad (`abfull`, seeds 0-2 where they exist)
compare("planned", "nodsp", (("seed 0", (0,)),))
compare("planned", "abfull", (("seed 0", (0,)), ("seeds 0-2", (0, 1, 2))))
