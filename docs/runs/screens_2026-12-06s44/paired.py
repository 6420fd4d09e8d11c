"""Session 44's LLFF pairs, seeds 0-2: the recipe (base), the 5-pixel window + 192 planes sweep (w5d192) and the
binocular smoothness at 0.1 (sw01).
usage: python paired.py [RUNS]  (RUNS: the bench's work folder, default /tmp/s44/runs; else the copies here)"""
import glob, json, os, statistics as st, sys

root = sys.argv[1] if len(sys.argv) > 1 else "/tmp/s44/runs"
here = os.path.dirname(os.path.abspath(__file__))


def cell(scene, tag, seed):
    f = f"{root}/llff/{scene}/{tag}/seed{seed}/result/metrics.json"
    if not os.path.exists(f):
        f = f"{here}/{scene}_{tag}_seed{seed}.metrics.json"
    return json.load(open(f))


for tag in ("base", "w5d192", "sw01"):
    means = []
    for k in range(3):
        ms = [cell(s, tag, k) for s in ("llff_flower", "llff_horns")]
        means.append([st.mean(m[key] for m in ms) for key in ("psnr", "ssim", "lpips_vgg")])
        print(tag, k, " ".join(f"{m['psnr']:.3f}" for m in ms))
    p, s, l = zip(*means)
    print(f"{tag}: PSNR {st.mean(p):.3f} +- {st.stdev(p):.3f}  SSIM {st.mean(s):.3f}  LPIPS {st.mean(l):.3f}")
