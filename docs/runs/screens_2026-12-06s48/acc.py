import sys, json, numpy as np, torch
from dataclasses import replace
from gsgs_engine.io.loader import load_scene
from gsgs_engine.init import mvs
def main():
    path = sys.argv[1]
    scene = load_scene(path, train_views=3)
    train = scene.train; pool = scene.split("all_train")
    log = lambda m: None
    oracle = mvs.dense_and_sparse_points(scene, pool, 0, mvs.MVSConfig(sweep_budget=1e10, max_points=10**7), True, log)[0]
    res = {}
    for name, over in json.loads(sys.argv[2]).items():
        pts = mvs.dense_and_sparse_points(scene, train, 0, replace(mvs.MVSConfig(), **over), True, log)[0]
        out = []
        for v in train:
            cam = v.camera
            def zbuf(P):
                uv, z = cam.project(P); u = np.floor(uv[:, 0]).astype(int); w = np.floor(uv[:, 1]).astype(int)
                ok = (z > 0) & (u >= 0) & (u < cam.width) & (w >= 0) & (w < cam.height)
                D = np.full((cam.height, cam.width), np.inf); np.minimum.at(D, (w[ok], u[ok]), z[ok]); return D, (u, w, z, ok)
            Do, _ = zbuf(oracle)
            # each 3-view point against the oracle's front surface at its pixel
            _, (u, w, z, ok) = zbuf(pts)
            do = Do[w[ok], u[ok]]; has = np.isfinite(do); rel = (z[ok][has] - do[has]) / do[has]
            Dp, _ = zbuf(pts)
            cov_o = np.isfinite(Do); cov_p = np.isfinite(Dp)
            out.append({"points_in_view": int(ok.sum()), "within1%": float((np.abs(rel) < 0.01).mean()), "within5%": float((np.abs(rel) < 0.05).mean()),
                        "in_front>5%": float((rel < -0.05).mean()), "behind>5%": float((rel > 0.05).mean()),
                        "oracle_px_covered": float((cov_o & cov_p).sum() / max(cov_o.sum(), 1))})
        res[name] = {k: round(float(np.mean([o[k] for o in out])), 3) for k in out[0]}
        print(name, len(pts), res[name], flush=True)
if __name__ == "__main__":
    main()
