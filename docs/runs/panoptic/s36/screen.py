import subprocess, sys, os
# usage: [FIRST_FRAME=10] screen.py "tree:tag:cams:seed:models:iters:pfi" ...   (two at a time, one pinned to each
# core; FIRST_FRAME: another time window, frames FIRST_FRAME..+9 -- the w10* results ran with FIRST_FRAME=10)
T = {3: "exposure,dropout,opacity_decay", 6: "exposure,dropout,opacity_decay", 9: "exposure"}
def cmd(tree, tag, c, s, models, it, pfi, core):
    out = f"/tmp/s36/pan/{tag}_c{c}_s{s}"
    args = ["taskset", "-c", str(core), "/work/main/.venv/bin/python", "-m", "gsgs_engine", "bench", "dynamic",
            "--data", "/work/shared/data/panoptic_basketball", "--cameras", str(c), "--frames", "10",
            *(["--first-frame", os.environ["FIRST_FRAME"]] if os.environ.get("FIRST_FRAME") else []),
            "--resolution-scale", "0.5", "--iters", it, "--per-frame-iters", pfi, "--sh-degree", "0", "--no-lpips",
            "--threads", "1", "--init", "mvs", "--techniques", T[c], "--background", "sphere", "--position-lr-scale", "3",
            "--seed", str(s), "--rig", "inward", "--models", models, "--out", out]
    return args, open(out + ".log", "w"), tree
jobs = sys.argv[1:]
for i in range(0, len(jobs), 2):
    procs = []
    for core, j in enumerate(jobs[i:i+2]):
        tree, tag, c, s, models, it, pfi = j.split(":")
        a, log, tree = cmd(tree, tag, int(c), int(s), models, it, pfi, core)
        procs.append(subprocess.Popen(a, stdout=log, stderr=subprocess.STDOUT, env=dict(os.environ, PYTHONPATH=tree), cwd="/tmp"))
    for p in procs: p.wait()
    print("done", jobs[i:i+2], flush=True)
