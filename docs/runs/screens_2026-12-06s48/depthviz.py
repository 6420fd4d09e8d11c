import sys, time, json, numpy as np, torch, cv2
from dataclasses import replace
from gsgs_engine.io.loader import load_scene
from gsgs_engine.init import mvs
from gsgs_engine.init.views import working_view
from gsgs_engine.sfm import triangulate_known_poses
def main():
    scene_path = sys.argv[1]; out = sys.argv[2]; variants = json.loads(sys.argv[3])
    scene = load_scene(scene_path, train_views=3)
    tv = scene.train
    sparse, _ = triangulate_known_poses(tv); sparse = np.asarray(sparse, np.float32).reshape(-1, 3)
    base = mvs.MVSConfig()
    side = mvs.working_side(tv, base)
    views = []
    for v in tv:
        cam, rgb, mask = working_view(v, side, base.alpha_threshold)
        lo, hi = mvs.depth_range(v.camera, sparse, None, scene.near, scene.far)
        rgb_t = torch.from_numpy(rgb); views.append(mvs._WorkView(cam, rgb_t @ torch.tensor([0.299, 0.587, 0.114]), rgb_t, torch.from_numpy(mask), lo, hi))
    rows = []
    for name, over in variants.items():
        cfg = replace(base, **over)
        t = time.time(); depths = [mvs.estimate_depth(i, views, cfg)[0] for i in range(len(views))]; dt = time.time() - t
        kept = []
        need = 1
        for i in range(len(views)):
            cnt = mvs.consistent_views(i, depths, views, cfg); kept.append(torch.isfinite(depths[i]) & (cnt >= need))
        print(name, f"{dt:.1f}s", "matched", [int(torch.isfinite(d).sum()) for d in depths], "consistent", [int(k.sum()) for k in kept])
        row = []
        for i in range(len(views)):
            d = depths[i].clone(); d[~kept[i]] = float('nan')
            inv = 1 / d; lo, hi = 1 / views[i].far, 1 / views[i].near
            img = ((inv - lo) / (hi - lo)).nan_to_num(0).clamp(0, 1).numpy()
            row.append(cv2.applyColorMap((img * 255).astype(np.uint8), cv2.COLORMAP_TURBO) * (np.isfinite(d.numpy()))[..., None])
        rows.append(np.concatenate(row, 1))
    rgbrow = np.concatenate([(v.rgb.numpy()[..., ::-1] * 255).astype(np.uint8) for v in views], 1)
    cv2.imwrite(out, np.concatenate([rgbrow] + rows, 0))
    
if __name__ == "__main__":
    main()
