"""Session 34: how much of an LLFF test view's error lies in pixels no training photo sees.

For a trained result (PLY) of a protocol cell: each test view is rendered; its pixels are split by warping them
(with the rendered depth) into the training photos, as the warp-inpaint prior does (gsgs_engine.priors.warp_inpaint
.warp_photos: visible in a photo within 5 % of that photo's rendered depth). Printed per view: PSNR, the share of
pixels no photo sees, PSNR over the seen and unseen pixels, and the PSNR the view would have if the unseen pixels
were exact (the ceiling that better geometry alone can reach without any content the photos do not show).
usage: python unseen_split.py DATA_DIR TRAIN_VIEWS PLY
"""
import numpy as np
import torch

exec(open(__import__('os').path.join(__import__('os').path.dirname(__file__), 'common.py')).read())

psnr = lambda mse: float(10 * np.log10(1.0 / max(mse, 1e-12)))
print(f"{'view':28s} {'PSNR':>6s} {'unseen %':>8s} {'seen dB':>8s} {'unseen dB':>9s} {'unseen exact':>12s} {'err share unseen':>16s}")
rows = []
for v in scene.test:
    truth = img(v)
    o = render_at(v.camera)
    _, holes, _ = warp_photos(v.camera, o.color, o.depth, o.alpha, photos)
    covered = surface_depth(o.depth, o.alpha) > 0
    unseen = holes | ~covered
    se = ((o.color.clamp(0, 1) - truth) ** 2).mean(-1)
    n = se.numel()
    share = float(unseen.float().mean())
    mse_all = float(se.mean())
    mse_seen = float(se[~unseen].mean()) if (~unseen).any() else float("nan")
    mse_unseen = float(se[unseen].mean()) if unseen.any() else float("nan")
    exact = float(se[~unseen].sum()) / n
    rows.append((psnr(mse_all), share, psnr(exact)))
    print(f"{v.name:28s} {psnr(mse_all):6.2f} {100 * share:8.1f} {psnr(mse_seen):8.2f} {psnr(mse_unseen) if unseen.any() else float('nan'):9.2f} "
          f"{psnr(exact):12.2f} {float(se[unseen].sum()) / max(float(se.sum()), 1e-12):16.2f}")
m = np.mean(rows, axis=0)
print(f"{'mean':28s} {m[0]:6.2f} {100 * m[1]:8.1f} {'':8s} {'':9s} {m[2]:12.2f}")
