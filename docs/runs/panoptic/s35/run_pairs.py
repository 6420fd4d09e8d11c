# run bench-dynamic jobs two at a time, one pinned to each core. usage: run_pairs.py TAG PFI MODELS "c,s" ...
import subprocess, sys, os
tag, pfi, models, *jobs = sys.argv[1:]
T = {3: "exposure,dropout,opacity_decay", 6: "exposure,dropout,opacity_decay", 9: "exposure"}
def cmd(c, s, core):
    extra = ["--rig", "inward"] if c == 3 else []
    out = f"/tmp/s35/pan/{tag}_c{c}_s{s}"
    args = ["taskset", "-c", str(core), "/work/main/.venv/bin/python", "-m", "gsgs_engine", "bench", "dynamic",
            "--data", "/work/shared/data/panoptic_basketball", "--cameras", str(c), "--frames", "10",
            "--resolution-scale", "0.5", "--iters", "1000", "--per-frame-iters", pfi, "--sh-degree", "0", "--no-lpips",
            "--threads", "1", "--init", "mvs", "--techniques", T[c], "--background", os.environ.get("BG", "sphere"), "--position-lr-scale", "3",
            "--seed", str(s), *extra, "--models", models, "--out", out]
    return args, open(out + ".log", "w")
env = dict(os.environ)
pairs = [jobs[i:i + 2] for i in range(0, len(jobs), 2)]
for pair in pairs:
    procs = []
    for core, j in enumerate(pair):
        c, s = (int(x) for x in j.split(","))
        a, log = cmd(c, s, core)
        procs.append(subprocess.Popen(a, stdout=log, stderr=subprocess.STDOUT, env=env))
    for p in procs:
        p.wait()
    print("done", pair, flush=True)
