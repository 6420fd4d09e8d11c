"""Session 34: what fill of a test view's unseen pixels scores best (post-process on the render, no training).
usage: python fill_oracle.py DATA_DIR TRAIN_VIEWS PLY"""
import sys
import cv2
import numpy as np
import torch
exec(open(__import__('os').path.join(__import__('os').path.dirname(__file__), 'common.py')).read())

def pushpull(image, known, levels=8):
    """Fill unknown pixels from a mask-weighted image pyramid (push-pull): smooth, low-frequency."""
    img = image * known[..., None]
    w = known.astype(np.float32)
    pyr = [(img, w)]
    for _ in range(levels):
        i, ww = pyr[-1]
        if min(i.shape[:2]) < 4:
            break
        pyr.append((cv2.pyrDown(i), cv2.pyrDown(ww)))
    i, ww = pyr[-1]
    filled = i / np.maximum(ww, 1e-6)[..., None]
    for (i, ww) in reversed(pyr[:-1]):
        up = cv2.resize(filled, (i.shape[1], i.shape[0]), interpolation=cv2.INTER_LINEAR)
        cur = i / np.maximum(ww, 1e-6)[..., None]
        a = np.clip(ww, 0, 1)[..., None]
        filled = a * cur + (1 - a) * up
    return np.where(known[..., None], image, filled)

for v in scene.test:
    truth = img(v).numpy()
    o = render_at(v.camera)
    _, holes, _ = warp_photos(v.camera, o.color, o.depth, o.alpha, photos)
    unseen = (holes | ~(surface_depth(o.depth, o.alpha) > 0)).numpy()
    r = o.color.clamp(0, 1).numpy()
    if not unseen.any():
        continue
    def p(x):
        return 10 * np.log10(1 / ((x[unseen] - truth[unseen]) ** 2).mean())
    u8 = (r * 255).round().astype(np.uint8)
    tel = cv2.inpaint(u8, unseen.astype(np.uint8) * 255, 3, cv2.INPAINT_TELEA).astype(np.float32) / 255
    pp = pushpull(r.astype(np.float32), ~unseen)
    blur = cv2.GaussianBlur(r, (0, 0), 8)
    mean = np.where(unseen[..., None], r[~unseen].mean(0), r)
    print(f"{v.name:12s} unseen {100*unseen.mean():5.1f}%  render {p(r):6.2f}  telea-from-seen {p(tel):6.2f}  push-pull {p(pp):6.2f}  render blurred s8 {p(blur):6.2f}  seen mean colour {p(mean):6.2f}")
