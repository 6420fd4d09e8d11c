"""Issue 31 with the background sphere's texture at learning rate 0.01 (session 36) against 0.05 (session 35): every
model, seeds 0-2. `python docs/runs/panoptic/s36/table.py` (from the repository root) prints the tables from the results
kept beside it and in ../s35 (sph01_cC_sS.json: screen.py ...:sph01:C:S:4d,static_all,static_per_frame:1000:300;
pf100sph01_cC_sS.json: the per-frame models at 100 steps a frame, the 4D model's step total)."""
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
S35 = HERE.parent / "s35"


def load(path):
    return json.loads(path.read_text()) if path.is_file() else None


def cell(m):
    return f"{m['psnr']:.2f} / {m['psnr_region']:.2f}" if m else "-"


def stats(xs, sign=""):
    xs = np.asarray(xs, float)
    mean = format(xs.mean(), sign + ".2f")
    return f"{mean} ± {xs.std(ddof=1):.2f}" if len(xs) > 1 else mean


for label, tag, base in (("the sphere, texture learning rate 0.01 (session 36)", "sph01", HERE),
                         ("the sphere, texture learning rate 0.05 (session 35)", "sph", S35)):
    print(f"\n{label}:\n")
    print("| cameras, seed | 4D PSNR / region | static, all frames | static per frame, 300 steps | static per frame, "
          "100 steps | 4D lead (region) | 4D Gaussians |")
    print("|---|---|---|---|---|---|---|")
    summary = {}
    for cams in (3, 6, 9):
        for seed in (0, 1, 2):
            d = load(base / f"{tag}_c{cams}_s{seed}.json")
            if d is None:
                continue
            pf = load(base / f"pf100{tag}_c{cams}_s{seed}.json")
            pf100 = pf["static_per_frame"] if pf else None
            statics = [m for m in (d["static_all"], d["static_per_frame"], pf100) if m]
            best = max(m["psnr"] for m in statics)
            best_region = max(m["psnr_region"] for m in statics)
            lead, lead_region = d["4d"]["psnr"] - best, d["4d"]["psnr_region"] - best_region
            summary.setdefault(cams, []).append((d["4d"]["psnr"], d["4d"]["psnr_region"], lead, lead_region))
            print(f"| {cams}, seed {seed} | {cell(d['4d'])} | {cell(d['static_all'])} | {cell(d['static_per_frame'])} | "
                  f"{cell(pf100)} | {lead:+.2f} ({lead_region:+.2f}) | {d['4d']['num_gaussians']:,} |")
    for cams, rows in summary.items():
        a = np.array(rows)
        print(f"- {cams} cameras, seeds {len(rows)}: 4D {stats(a[:, 0])} (region {a[:, 1].mean():.2f}), lead over the "
              f"best static model {stats(a[:, 2], '+')} (region {a[:, 3].mean():+.2f})")
