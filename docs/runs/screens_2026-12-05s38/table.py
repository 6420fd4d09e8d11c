"""Session 38's screens (docs/sparse_techniques.md "Session 38"): one row per protocol x variant, the mean over the
seeds present of PSNR / SSIM / LPIPS (VGG) / train seconds / Gaussians, and each scene's PSNR per seed.
python docs/runs/screens_2026-12-05s38/table.py [FOLDER]   (FOLDER: another session's screens, e.g. ../screens_2026-12-05s39)"""
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

cells = defaultdict(dict)
for f in sorted((Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).parent).glob("*_seed*.json")):
    protocol, rest = f.stem.split("_", 1)
    m = json.loads(f.read_text())
    for scene in ("blender_lego", "blender_chair", "llff_flower", "llff_horns"):
        if rest.startswith(scene + "_"):
            variant, seed = rest[len(scene) + 1:].rsplit("_seed", 1)
            cells[(protocol, variant)][(scene, int(seed))] = m
for (protocol, variant), got in sorted(cells.items()):
    scenes = sorted({s for s, _ in got})
    seeds = sorted({k for _, k in got if all((s, k) in got for s in scenes)})
    if len(scenes) < 2 or not seeds:
        continue
    ms = [got[(s, k)] for s in scenes for k in seeds]
    per = "; ".join(f"{s.split('_')[1]} " + " / ".join(f"{got[(s, k)]['psnr']:.2f}" for k in seeds) for s in scenes)
    print(f"{protocol:8s} {variant:8s} seeds {','.join(map(str, seeds)):6s} PSNR {np.mean([m['psnr'] for m in ms]):.3f}"
          f" SSIM {np.mean([m['ssim'] for m in ms]):.3f} LPIPS {np.mean([m['lpips'] for m in ms]):.3f}"
          f" {np.mean([m['train_seconds'] for m in ms]):.0f} s {np.mean([m['num_gaussians'] for m in ms]) / 1000:.1f}k"
          f" | {per}")
