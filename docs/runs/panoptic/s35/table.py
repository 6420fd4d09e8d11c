"""Issue 31 with the background sphere (session 35): every model, seeds 0-2, against session 34's runs with the photos'
mean colour. `python docs/runs/panoptic/s35/table.py` (from the repository root) prints the tables from the results
kept beside it (sph_cC_sS.json: run_pairs.py sph 300 ...; pf100sph_cC_sS.json: the per-frame models at 100 steps a
frame, the 4D model's step total)."""
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
S34 = HERE.parent / "s34"


def load(path):
    return json.loads(path.read_text()) if path.is_file() else None


def cell(m):
    return f"{m['psnr']:.2f} / {m['psnr_region']:.2f}" if m else "-"


def stats(xs, sign=""):
    xs = np.asarray(xs, float)
    mean = format(xs.mean(), sign + ".2f")
    return f"{mean} ± {xs.std(ddof=1):.2f}" if len(xs) > 1 else mean


def print_table(label, tag, base, pf100_name):
    """One set of results (`tag`_cC_sS.json in `base`, the 100-step per-frame runs in pf100_name(cams, seed))."""
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
            pf = load(base / pf100_name(cams, seed))
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


if __name__ == "__main__":
    print_table("the background sphere (session 35)", "sph", HERE, lambda c, s: f"pf100sph_c{c}_s{s}.json")
    print_table("the mean colour (session 34)", "full", S34, lambda c, s: f"pf100_c{c}_s{s}.json")
