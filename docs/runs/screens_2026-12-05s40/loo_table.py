"""Session 40's screens (docs/sparse_techniques.md "Session 40"): seed-0 cells of today's `--prior auto` recipe with
one piece left out, per protocol: each scene's PSNR, the mean and its difference from the recipe (`planned`), SSIM and
LPIPS (VGG) over the two scenes, the two cells' training seconds summed and the Gaussians per cell.
python docs/runs/screens_2026-12-05s40/loo_table.py [SEED]"""
import json
import sys
from pathlib import Path

here = Path(__file__).parent
seed = int(sys.argv[1]) if len(sys.argv) > 1 else 0
for protocol, scenes in (("blender", ("blender_lego", "blender_chair")), ("llff", ("llff_flower", "llff_horns"))):
    cells = {}
    for f in here.glob(f"{protocol}_*_seed{seed}.json"):
        for s in scenes:
            if f.stem.startswith(f"{protocol}_{s}_"):
                cells[(f.stem[len(protocol) + len(s) + 2:].rsplit("_seed", 1)[0], s)] = json.loads(f.read_text())
    variants = sorted({v for v, _ in cells if all((v, s) in cells for s in scenes)}, key=lambda v: v != "planned")
    base = sum(cells[("planned", s)]["psnr"] for s in scenes) / 2 if "planned" in variants else None
    print(f"| {protocol} seed {seed} | " + " | ".join(s.split("_")[1] for s in scenes)
          + " | mean | vs recipe | SSIM | LPIPS | train s (both) | Gaussians |")
    for v in variants:
        ms = [cells[(v, s)] for s in scenes]
        mean = sum(m["psnr"] for m in ms) / 2
        print(f"| {v} | " + " | ".join(f"{m['psnr']:.2f}" for m in ms) + f" | {mean:.3f} | "
              + (f"{mean - base:+.2f}" if base is not None else "") + f" | {sum(m['ssim'] for m in ms) / 2:.3f} | "
              f"{sum(m['lpips'] for m in ms) / 2:.3f} | {sum(m['train_seconds'] for m in ms):.0f} | "
              + " / ".join(f"{m['num_gaussians'] / 1000:.1f}k" for m in ms) + " |")
    print()
