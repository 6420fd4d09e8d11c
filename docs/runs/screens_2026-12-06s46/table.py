"""Session 46's paired screens: `python docs/runs/screens_2026-12-06s46/table.py` prints each variant against the
forward recipe's cells of the same scene and seed (session 45's `attr3` cells at 1000 steps; 300- and 3000-step
references ran this session or in session 45: tags fastbase / fastattr3 / L3kbase)."""
import json
import statistics as st
from pathlib import Path

HERE = Path(__file__).resolve().parent
S45 = HERE.parent / "screens_2026-12-06s45"


def load(path):
    d = json.loads(Path(path).read_text())
    return d.get("metrics", d)


def cell(scene, tag, seed):
    for folder in (HERE, S45):
        p = folder / f"{scene}_{tag}_seed{seed}.metrics.json"
        if p.exists():
            return load(p)
    return None


def views(m):
    pv = m["per_view"]
    return [round(v["psnr"] if isinstance(v, dict) else v, 2) for v in (pv.values() if isinstance(pv, dict) else pv)]


def pair(tag, ref, seeds, scenes=("llff_flower", "llff_horns")):
    rows = []
    for k in seeds:
        for s in scenes:
            a, b = cell(s, ref, k), cell(s, tag, k)
            if a is None or b is None:
                continue
            rows.append((s, k, a, b))
            print(f"  {s:12s} seed {k}: {a['psnr']:.2f} -> {b['psnr']:.2f} ({b['psnr'] - a['psnr']:+.2f})  "
                  f"SSIM {a['ssim']:.3f} -> {b['ssim']:.3f}  LPIPS {a['lpips']:.3f} -> {b['lpips']:.3f}  "
                  f"train s {a['train_seconds']:.0f} -> {b['train_seconds']:.0f}  views {views(b)}")
    full = [k for k in seeds if all(cell(s, tag, k) and cell(s, ref, k) for s in scenes)]
    if full:
        for name, t in ((ref, ref), (tag, tag)):
            means = [st.mean(cell(s, t, k)["psnr"] for s in scenes) for k in full]
            cs = [cell(s, t, k) for s in scenes for k in full]
            sd = f" ± {st.stdev(means):.2f}" if len(means) > 1 else ""
            print(f"  {name:10s} seeds {full}: LLFF {st.mean(means):.3f}{sd}  SSIM {st.mean(c['ssim'] for c in cs):.4f}"
                  f"  LPIPS {st.mean(c['lpips'] for c in cs):.4f}")


if __name__ == "__main__":
    for tag in ("dist01", "dist1", "opac2", "opac05", "pos05"):
        print(f"{tag} against attr3 (1000 steps)")
        pair(tag, "attr3", (0,))
    print("fastattr3 against fastbase (300 steps)")
    pair("fastattr3", "fastbase", (0, 1, 2))
    print("L3kattr3 against L3kbase (3000 steps)")
    pair("L3kattr3", "L3kbase", (0,))
    orbits = ("blender_lego", "blender_chair")
    print("odist0.1 against attr3 (the orbit recipe, 1000 steps)")
    pair("odist0.1", "attr3", (0,), orbits)
    print("odist1.0 against attr3 (the orbit recipe, 1000 steps)")
    pair("odist1.0", "attr3", (0, 1, 2), orbits)
