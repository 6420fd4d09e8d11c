import json, glob, os, numpy as np
rows = {}
for f in sorted(glob.glob('docs/runs/panoptic/s34/full_c*_s*.json')):
    tag = f.split('/')[-1][:-5]; c = int(tag.split('_')[1][1:]); s = int(tag.split('_')[2][1:])
    d = json.load(open(f))
    m = {k: d[k] for k in ('4d', 'static_all', 'static_per_frame') if k in d}
    best = max(m['static_all']['psnr'], m['static_per_frame']['psnr'])
    best_r = max(m['static_all']['psnr_region'], m['static_per_frame']['psnr_region'])
    lead, lead_r = m['4d']['psnr'] - best, m['4d']['psnr_region'] - best_r
    rows.setdefault(c, []).append((s, m['4d']['psnr'], m['4d']['psnr_region'], m['static_all']['psnr'], m['static_per_frame']['psnr'],
                                   m['static_per_frame']['psnr_region'], lead, lead_r, m['4d']['num_gaussians'], m['4d']['train_seconds']))
    print(f"| {c}, seed {s} | {m['4d']['psnr']:.2f} / {m['4d']['psnr_region']:.2f} | {m['static_all']['psnr']:.2f} / {m['static_all']['psnr_region']:.2f} | "
          f"{m['static_per_frame']['psnr']:.2f} / {m['static_per_frame']['psnr_region']:.2f} | {lead:+.2f} ({lead_r:+.2f}) | {m['4d']['num_gaussians']:,} | {m['4d']['train_seconds']:.0f} |")
for c, r in sorted(rows.items()):
    a = np.array([x[1:] for x in r])
    print(f"cameras {c} (n={len(r)}): 4D {a[:,0].mean():.2f} ± {a[:,0].std(ddof=1) if len(r)>1 else 0:.2f} / region {a[:,1].mean():.2f}; "
          f"static_all {a[:,2].mean():.2f}; per-frame {a[:,3].mean():.2f} / {a[:,4].mean():.2f}; lead {a[:,5].mean():+.2f} ± {a[:,5].std(ddof=1) if len(r)>1 else 0:.2f} (region {a[:,6].mean():+.2f})")
