"""The plan's triangulation of a protocol scene's training views alone, with its stages' seconds (session 42).

    PYTHONPATH=TREE python tri_time.py /work/shared/data/blender_lego   # the 8 NeRF-synthetic protocol views, 400 px
    PYTHONPATH=TREE python tri_time.py /work/shared/data/llff_flower    # the LLFF protocol's 3 views, full size

TREE with `triangulation_options_scratch.diff` applied reads S42_AFF / S42_DSP / S42_OCT (SIFT's affine shapes,
domain-size pooling, first octave at <= 400 px)."""
import sys
import tempfile
import time

from gsgs_engine.io.loader import load_scene
from gsgs_engine.sfm import triangulate_with_known_poses

BLENDER_IDS = ["r_2", "r_16", "r_26", "r_55", "r_73", "r_76", "r_86", "r_93"]  # the bench's lego cells' job.json

if __name__ == "__main__":
    path = sys.argv[1]
    if "llff" in path:
        scene = load_scene(path, train_views=3, resolution_scale=1.0)
    else:
        scene = load_scene(path, train_ids=BLENDER_IDS, resolution_scale=0.5, background=[1.0, 1.0, 1.0])
    start = time.perf_counter()

    def progress(stage, step, total, message):
        print(f"  {time.perf_counter() - start:6.2f} s  {stage}: {message[:100]}")

    with tempfile.TemporaryDirectory() as work:
        tri = triangulate_with_known_poses(scene.train, progress=progress, out_dir=work)
    print(f"triangulate {time.perf_counter() - start:.2f} s, {len(tri.points)} points")
