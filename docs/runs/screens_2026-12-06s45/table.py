"""Session 45's paired screens: `python docs/runs/screens_2026-12-06s45/table.py` prints each variant against the
recipe's cells of the same scene and seed (this VM reproduces sessions 43-44's recipe cells to the digit; the
300-step recipe cells ran this session, tag fastbase)."""
import json
import statistics as st
from pathlib import Path

HERE = Path(__file__).resolve().parent
S44 = HERE.parent / "screens_2026-12-06s44"
S43 = HERE.parent / "screens_2026-12-05s43"


def load(path):
    d = json.loads(Path(path).read_text())
    return d.get("metrics", d)


def cell(scene, tag, seed):
    if tag == "base":  # the 1000-step recipe, sessions 43 (seed 0) and 44 (seeds 1-2)
        p = S43 / f"{'blender' if 'blender' in scene else 'llff'}_{scene}_base_seed0.json" if seed == 0 else \
            S44 / f"{scene}_base_seed{seed}.metrics.json"
        if not p.exists():
            p = S44 / f"{scene}_base_seed{seed}.metrics.json"
    else:
        p = HERE / f"{scene}_{tag}_seed{seed}.metrics.json"
    return load(p) if p.exists() else None


def table(scenes, tags, seeds=(0, 1, 2)):
    for tag in tags:
        rows = {s: [cell(s, tag, k) for k in seeds] for s in scenes}
        if any(c is None for cs in rows.values() for c in cs):
            have = {s: [k for k, c in zip(seeds, cs) if c] for s, cs in rows.items()}
            print(f"{tag:14s} incomplete: seeds {have}")
            continue
        means = [st.mean(rows[s][i]["psnr"] for s in scenes) for i in range(len(seeds))]
        per = " | ".join(f"{s.split('_')[1]} " + " / ".join(f"{c['psnr']:.2f}" for c in rows[s]) for s in scenes)
        allc = [c for cs in rows.values() for c in cs]
        sd = st.stdev(means) if len(means) > 1 else 0.0
        print(f"{tag:14s} {per} | mean {st.mean(means):.2f} ± {sd:.2f} | SSIM {st.mean(c['ssim'] for c in allc):.3f} "
              f"LPIPS {st.mean(c.get('lpips_vgg', c.get('lpips')) for c in allc):.3f} | train s "
              + " ".join(f"{c['train_seconds']:.0f}" for c in allc))


if __name__ == "__main__":
    print("NeRF-synthetic 8 views, 1000 steps")
    table(["blender_lego", "blender_chair"], ["base", "attr3"])
    table(["blender_lego", "blender_chair"], ["unpool", "up6o5"], seeds=(0,))
    print("lego seed 0, the timing pairs (q13.sh: the build before, then this one, twice)")
    for tag in ("timebase1", "timehead1", "timebase2", "timehead2"):
        c = cell("blender_lego", tag, 0)
        print(f"{tag:14s} {c['psnr']:.3f} dB, {c['train_seconds']:.1f} s of training, {c['num_gaussians']} Gaussians")
    print("NeRF-synthetic 8 views, 300 steps (the fast preset)")
    table(["blender_lego", "blender_chair"], ["fastbase", "fastattr3"])
    print("LLFF 3 views, 1000 steps")
    table(["llff_flower", "llff_horns"], ["base", "black", "attr3"])
    table(["llff_flower", "llff_horns"], ["whitenoreset"], seeds=(0, 1))
    table(["llff_flower", "llff_horns"], ["mp40k", "blackreset"], seeds=(0,))
    print("LLFF 3 views, 300 steps (the fast preset), seed 0")
    table(["llff_flower", "llff_horns"], ["fastbase", "fastattr3"], seeds=(0,))
