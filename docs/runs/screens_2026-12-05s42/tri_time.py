import sys, time
t0 = time.perf_counter()
from gsgs_engine.io.loader import load_scene
from gsgs_engine.sfm import triangulate_with_known_poses
print("imports", round(time.perf_counter() - t0, 2))
if __name__ == "__main__":
    import glob, json
    spec = sys.argv[1]
    t = time.perf_counter()
    scene = load_scene(spec, train_ids=["r_2","r_16","r_26","r_55","r_73","r_76","r_86","r_93"], resolution_scale=0.5, background=[1.0,1.0,1.0])
    print("load", round(time.perf_counter() - t, 2), len(scene.train))
    views = scene.train
    last = [time.perf_counter()]
    def prog(stage, step, total, msg):
        now = time.perf_counter(); print(f"  {now - t1:6.2f} s  {stage}: {msg[:100]}"); 
    t1 = time.perf_counter()
    tri = triangulate_with_known_poses(views, progress=prog, out_dir="/tmp/s42/tri_work")
    print("triangulate", round(time.perf_counter() - t1, 2), len(tri.points) if hasattr(tri, 'points') else tri)
