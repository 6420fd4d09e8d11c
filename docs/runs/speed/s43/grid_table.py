"""Issue 29's grid at equal quality (session 43): f6f2ab9's `--prior auto` (1000 steps) against this build's at N
steps, pairs of one scene and seed run one after the other. Reads /tmp/f6/w/{old,new} (or the copies in the docs
folder given as argument: FOLDER/{old,new}_PROTOCOL_SCENE_seedK.json)."""
import glob, json, statistics, sys
from pathlib import Path

def cells(tag):
    out = {}
    if len(sys.argv) > 1:
        for f in glob.glob(f"{sys.argv[1]}/{tag}_*_seed*.json"):
            name = Path(f).stem[len(tag) + 1:]
            proto, rest = name.split("_", 1)
            scene, seed = rest.rsplit("_seed", 1)
            out[(proto, scene, int(seed))] = json.load(open(f))
    else:
        for f in glob.glob(f"/tmp/f6/w/{tag}/*/*/*/seed*/result/metrics.json"):
            p = f.split("/")
            out[(p[-6], p[-5], int(p[-3][4:]))] = json.load(open(f))
    return out

old, new = cells("old"), cells("new")
print("| scene | seed | f6f2ab9 (1000 steps) train s / PSNR | this build train s / PSNR (steps) | ratio |\n|---|---|---|---|---|")
sums = {}
for k in sorted(old):
    if k not in new:
        continue
    o, n = old[k], new[k]
    print(f"| {k[1]} | {k[2]} | {o['train_seconds']:.1f} / {o['psnr']:.2f} | {n['train_seconds']:.1f} / {n['psnr']:.2f} ({n['iterations']}) | {o['train_seconds'] / n['train_seconds']:.2f}x |")
    s = sums.setdefault(k[0], {"os": 0, "ns": 0, "op": {}, "np": {}, "nl": {}, "ol": {}})
    s["os"] += o["train_seconds"]; s["ns"] += n["train_seconds"]
    s["op"].setdefault(k[2], []).append(o["psnr"]); s["np"].setdefault(k[2], []).append(n["psnr"])
    s["ol"].setdefault(k[2], []).append(o["lpips"] or 0); s["nl"].setdefault(k[2], []).append(n["lpips"] or 0)
for proto, s in sums.items():
    op = [statistics.mean(v) for v in s["op"].values()]; npp = [statistics.mean(v) for v in s["np"].values()]
    sd = lambda v: statistics.stdev(v) if len(v) > 1 else 0.0
    print(f"{proto}: {len(s['op'])} seeds, train s {s['os']:.1f} -> {s['ns']:.1f} ({s['os'] / s['ns']:.2f}x); "
          f"PSNR {statistics.mean(op):.2f} ± {sd(op):.2f} -> {statistics.mean(npp):.2f} ± {sd(npp):.2f}; "
          f"LPIPS {statistics.mean(sum(s['ol'].values(), [])):.3f} -> {statistics.mean(sum(s['nl'].values(), [])):.3f}")
