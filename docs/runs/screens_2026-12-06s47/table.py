"""Session 47's screens: `python docs/runs/screens_2026-12-06s47/table.py` prints the depth distortion every K steps on
the orbit recipe against session 45's cells of the same scene and seed (tag `attr3` at 1000 steps, `fastattr3` at 300:
today's `--prior auto` without the term), session 46's weight 1 at every step, the recipe at 1200 steps, and the
alternating timing pairs (lego seed 0)."""
import json
import statistics as st
from pathlib import Path

HERE = Path(__file__).resolve().parent
FOLDERS = (HERE, HERE.parent / "screens_2026-12-06s46", HERE.parent / "screens_2026-12-06s45")
SCENES = ("blender_lego", "blender_chair")


def cell(scene, tag, seed):
    for folder in FOLDERS:
        p = folder / f"{scene}_{tag}_seed{seed}.metrics.json"
        if p.exists():
            d = json.loads(p.read_text())
            return d.get("metrics", d)
    return None


def row(name, tag, seeds=(0, 1, 2)):
    cells = {(s, k): cell(s, tag, k) for s in SCENES for k in seeds}
    parts = [" / ".join(f"{cells[(s, k)]['psnr']:.2f}" if cells[(s, k)] else "-" for k in seeds) for s in SCENES]
    means = [st.mean(cells[(s, k)]["psnr"] for s in SCENES) for k in seeds if all(cells[(s, k)] for s in SCENES)]
    done = [m for m in cells.values() if m]
    if len(means) > 1:
        mean = f"{st.mean(means):.2f} ± {st.stdev(means):.2f}"
    else:
        mean = f"({means[0]:.2f} on seed {seeds[0]})" if means else "-"
    ssim = st.mean(m["ssim"] for m in done)
    lpips = st.mean(m.get("lpips_vgg", m["lpips"]) for m in done)
    print(f"| {name} | {parts[0]} | {parts[1]} | {mean} | {ssim:.3f} | {lpips:.3f} |")


print("| NeRF-synthetic 8 views | lego seeds 0 / 1 / 2 | chair seeds 0 / 1 / 2 | mean ± std over seeds | SSIM | LPIPS (VGG) |")
print("|---|---|---|---|---|---|")
row("1000 steps: the recipe (session 45)", "attr3")
row("+ weight 1 every step (session 46)", "odist1.0")
row("+ weight 3 every 4th step", "dev4w3")
row("+ weight 6 every 8th step", "dev8w6")
row("+ weight 12 every 16th step", "dev16w12", seeds=(0,))
row("the recipe at 1200 steps", "it1200", seeds=(0,))
row("300 steps: the recipe (session 45)", "fastattr3")
row("+ weight 3 every 4th step", "fdev4w3")
row("+ weight 6 every 8th step", "fdev8w6")
row("3000 steps: the long recipe (this session)", "L3kbase", seeds=(0,))
row("+ distortion (weight 6 every 8th step)", "L3kdist", seeds=(0,))
print()
print("timing pairs, lego seed 0, seconds of training (run in this order, one at a time):")
for tag in ("tbase1", "tdist1", "tbase2", "tdist2", "tbase3", "t8dist3", "tbase4", "t8dist4"):
    m = cell("blender_lego", tag, 0)
    if m:
        print(f"  {tag}: {m['train_seconds']:.1f} s, {m['psnr']:.3f} dB")
