"""Issue 29's pinned grid as a table: train seconds and PSNR of f6f2ab9 and this build per cell, the ratios per scene and
protocol (sums of seconds over the cells both builds finished), PSNR means. python grid_table.py [WORK]"""
import json
import sys
from pathlib import Path

work = Path(sys.argv[1] if len(sys.argv) > 1 else "/tmp/f6/w")
cells = {}
for tag in ("old", "new"):
    for f in sorted((work / tag).glob("*/*/auto/seed*/result/metrics.json")):
        m = json.loads(f.read_text())
        scene, seed = f.parts[-5], int(f.parts[-3][4:])
        cells[(tag, scene, seed)] = (m["train_seconds"], m["psnr"], m["num_gaussians"])
print("| scene | seed | f6f2ab9 train s / PSNR | this build train s / PSNR | ratio | PSNR change |")
print("|---|---|---|---|---|---|")
proto = {"blender_lego": "NeRF-synthetic", "blender_chair": "NeRF-synthetic", "llff_flower": "LLFF", "llff_horns": "LLFF"}
sums = {}
for scene in proto:
    for seed in range(3):
        o, n = cells.get(("old", scene, seed)), cells.get(("new", scene, seed))
        if o is None or n is None:
            continue
        print(f"| {scene} | {seed} | {o[0]:.1f} / {o[1]:.2f} | {n[0]:.1f} / {n[1]:.2f} | {o[0] / n[0]:.2f}x | {n[1] - o[1]:+.2f} |")
        for key in (proto[scene], scene, "all"):
            s = sums.setdefault(key, [0.0, 0.0, [], [], 0])
            s[0] += o[0]; s[1] += n[0]; s[2].append(o[1]); s[3].append(n[1]); s[4] += 1
print()
print("| group | cells | f6f2ab9 train s | this build train s | ratio (sum / sum) | PSNR mean f6f2ab9 -> this build |")
print("|---|---|---|---|---|---|")
for key, (so, sn, po, pn, k) in sums.items():
    print(f"| {key} | {k} | {so:.1f} | {sn:.1f} | {so / sn:.2f}x | {sum(po) / k:.2f} -> {sum(pn) / k:.2f} ({(sum(pn) - sum(po)) / k:+.2f}) |")
