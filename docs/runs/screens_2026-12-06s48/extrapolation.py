"""Session 48: how far each LLFF test view lies from the nearest training camera, and each result's PSNR on the
left 60 % / right 40 % of flower's test views (the right 40 % of image008 / image024 is content no training photo shows).
usage: python extrapolation.py RESULT_DIR [RESULT_DIR ...]   (folders holding renders/NNN_imageXXX.png)"""
import sys, glob
import cv2
import numpy as np

DATA = "/work/shared/data/llff_flower"
pb = np.load(f"{DATA}/poses_bounds.npy")
centres = pb[:, :15].reshape(-1, 3, 5)[:, :, 3]
test = list(range(0, len(centres), 8))
pool = [i for i in range(len(centres)) if i not in test]
train = [pool[int(round(k))] for k in np.linspace(0, len(pool) - 1, 3)]
print("training images", train, "centres", centres[train].round(2).tolist())
for t in test:
    print(f"test image{t:03d}: centre {centres[t].round(2).tolist()}, {np.linalg.norm(centres[train] - centres[t], axis=1).min():.2f} "
          "from the nearest training camera")


def psnr(a, b):
    return 10 * np.log10(255 ** 2 / ((a - b) ** 2).mean())


for folder in sys.argv[1:]:
    for f in sorted(glob.glob(f"{folder}/renders/*.png")):
        name = f.rsplit("/", 1)[1].split("_", 1)[1]
        g = cv2.imread(f"{DATA}/images_8/{name}").astype(float)
        r = cv2.imread(f).astype(float)
        cut = int(r.shape[1] * 0.6)
        print(f"{folder} {name}: {psnr(r, g):.2f} (left 60 % {psnr(r[:, :cut], g[:, :cut]):.2f}, right 40 % "
              f"{psnr(r[:, cut:], g[:, cut:]):.2f})")
