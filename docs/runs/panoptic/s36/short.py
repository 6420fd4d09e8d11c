import subprocess, sys, os
# usage: short.py "iters,pfi,models" ...
jobs = sys.argv[1:]
def cmd(it, pfi, models, core):
    out = f"/tmp/s36/pan/sph_c3_s0_i{it}_pf{pfi}_{models.replace(',','+')}"
    args = ["taskset", "-c", str(core), "/work/main/.venv/bin/python", "-m", "gsgs_engine", "bench", "dynamic",
            "--data", "/work/shared/data/panoptic_basketball", "--cameras", "3", "--frames", "10",
            "--resolution-scale", "0.5", "--iters", it, "--per-frame-iters", pfi, "--sh-degree", "0", "--no-lpips",
            "--threads", "1", "--init", "mvs", "--techniques", "exposure,dropout,opacity_decay", "--background", "sphere", "--position-lr-scale", "3",
            "--seed", "0", "--rig", "inward", "--models", models, "--out", out]
    return args, open(out + ".log", "w")
env = dict(os.environ, PYTHONPATH="/tmp/frozen")
for i in range(0, len(jobs), 2):
    procs = []
    for core, j in enumerate(jobs[i:i+2]):
        it, pfi, models = j.split(":")
        a, log = cmd(it, pfi, models, core)
        procs.append(subprocess.Popen(a, stdout=log, stderr=subprocess.STDOUT, env=env, cwd="/tmp"))
    for p in procs: p.wait()
    print("done", jobs[i:i+2], flush=True)
