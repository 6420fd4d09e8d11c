"""The NeRF-synthetic protocol's lego initialisation (dense MVS + SfM points of the 8 training views at 400 px):
its point count and an MD5 of the points, to compare machines and math-library settings (session 32).

    cd /tmp && PYTHONPATH=/work/main /work/main/.venv/bin/python init_points_digest.py 2
    MKL_CBWR=AVX2 PYTHONPATH=... python init_points_digest.py 2     # MKL's AVX2 code path on an AVX-512 machine
"""
import hashlib
import sys

import torch

from gsgs_engine.init.mvs import MVSConfig, dense_and_sparse_points
from gsgs_engine.io.loader import load_scene

TRAIN_IDS = ["r_2", "r_16", "r_26", "r_55", "r_73", "r_76", "r_86", "r_93"]

if __name__ == "__main__":  # the SfM step runs in a spawned child process
    torch.set_num_threads(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
    scene = load_scene("/work/shared/data/blender_lego", train_ids=TRAIN_IDS, resolution_scale=0.5,
                       background=[1.0, 1.0, 1.0])
    points, _, _, reason = dense_and_sparse_points(scene, scene.train, 0, MVSConfig(), log=lambda *a: None)
    print(len(points), hashlib.md5(points.tobytes()).hexdigest(), reason)
