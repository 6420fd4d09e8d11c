"""`gsgs bench train-step`: milliseconds per training step on real scenes, old and new CPU kernel side by side.

Each cell (scene, Gaussian count, backend) runs in its own subprocess: the real Trainer on the
scene's training views, a model of exactly N Gaussians, SH degree 3 active, `--steps` timed
steps after `--warmup` untimed ones. The backends compared in one run are "cpu_legacy"
(projection and SH in torch, compositing compiled: the kernel before issue 17) and "cpu"
(projection, SH and compositing compiled); cells alternate between them so that load from
other processes falls on both alike. Reported: the median and the minimum step time.
A backend written `NAME@DIR` runs NAME from the gsgs checkout in DIR instead of this one (a pinned
build of an older commit, e.g. `git worktree add /tmp/old <commit>`; its extension builds into its
own hash-keyed folder): `--backends cpu@/tmp/old,cpu` compares today's kernel with that commit's.
An older checkout lacks the kernel's phase clocks: its compiled phases then show as "-" and its whole
render and backward phases under torch fwd / bwd.

The profile splits each step (averages over the timed steps, ms):
  proj+SH fwd / bwd   projection (EWA, eq. 2) and SH colour, compiled kernel (one fused pass each)
  binning             depth sort and per-tile lists (compiled)
  raster fwd / bwd    per-tile compositing and its backward, incl. rebuilding records and the
                      per-Gaussian reduction (compiled)
  torch fwd / bwd     everything else in the trainer's render and backward phases: the loss
                      (L1 + SSIM) and its backward, autograd bookkeeping, and for cpu_legacy the torch
                      projection + SH and their autograd
  optimiser           Adam and the densification statistics (trainer's "optimise" phase)
  densify             densify/prune/reset (the timed steps lie before densification starts, so ~0)
  loss alone          L1 + D-SSIM forward + backward on one image of this size, timed by itself
The compiled phases come from the kernel's own clocks (`gsgs_raster_cpu::phase_seconds`).

Fixed Gaussian counts are synthesised, not trained: N means uniform in the box the trainer's
random initialisation uses (scene_bounds_from_cameras), isotropic scales from the mean spacing
(V / N)^(1/3) (what 3DGS's nearest-neighbour init gives for uniform points, without its O(N^2)
search), random rotations, opacities uniform in [0.05, 0.95], random colours and small higher-order
SH. The same seed gives both backends the same model.
"""

from __future__ import annotations

import json
import math
import statistics
import subprocess
import sys
import time

from gsgs_engine import GsgsError

SCENES = {
    # name -> (folder under the data root, load_scene keyword arguments)
    "flower": ("llff_flower", {"train_views": 3}),
    "lego": ("blender_lego", {"train_views": 8, "resolution_scale": 0.5}),
}
DEFAULT_COUNTS = "20000,100000,300000"
DEFAULT_BACKENDS = "cpu_legacy,cpu"
PHASES = ("proj_fwd", "binning", "raster_fwd", "torch_fwd", "raster_bwd", "proj_bwd", "torch_bwd", "optimiser",
          "densify")
KERNEL_PHASES = ("proj_fwd", "binning", "raster_fwd", "bwd_prep", "raster_bwd", "bwd_reduce", "proj_bwd")


def add_arguments(parser) -> None:
    parser.add_argument("--data", default="../shared/data", help="folder holding llff_flower/ and blender_lego/")
    parser.add_argument("--scenes", default="flower,lego", help=f"comma-separated subset of {', '.join(SCENES)}")
    parser.add_argument("--counts", default=DEFAULT_COUNTS, help=f"Gaussian counts (default {DEFAULT_COUNTS})")
    parser.add_argument("--backends", default=DEFAULT_BACKENDS,
                        help=f"backends to compare, in this order (default {DEFAULT_BACKENDS})")
    parser.add_argument("--steps", type=int, default=8, help="timed training steps per cell (default 8)")
    parser.add_argument("--warmup", type=int, default=2, help="untimed steps first (default 2)")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--json", metavar="FILE", help="also write the rows as a JSON list to FILE")


def synthetic_model(scene, train_views, n: int, seed: int, sh_degree: int = 3):
    """A GaussianModel of exactly n Gaussians spread over the scene's initialisation box."""
    import numpy as np
    import torch

    from gsgs_engine.gaussians import GaussianModel, inverse_sigmoid, num_sh_coeffs, scene_bounds_from_cameras

    lo, hi = scene_bounds_from_cameras([v.camera for v in train_views], scene.near, scene.far)
    lo_t, hi_t = torch.as_tensor(lo, dtype=torch.float32), torch.as_tensor(hi, dtype=torch.float32)
    g = torch.Generator().manual_seed(seed)
    means = lo_t + (hi_t - lo_t) * torch.rand(n, 3, generator=g)
    spacing = float(np.prod(hi - lo) / n) ** (1.0 / 3.0)
    log_scales = torch.full((n, 3), math.log(0.5 * spacing)) + 0.3 * torch.randn(n, 3, generator=g)
    quats = torch.nn.functional.normalize(torch.randn(n, 4, generator=g), dim=-1)
    opacity_logits = inverse_sigmoid(0.05 + 0.9 * torch.rand(n, generator=g))
    sh_dc = ((torch.rand(n, 1, 3, generator=g) - 0.5) / 0.28209479177387814)
    sh_rest = 0.05 * torch.randn(n, num_sh_coeffs(sh_degree) - 1, 3, generator=g)
    return GaussianModel(means, log_scales, quats, opacity_logits, sh_dc, sh_rest, sh_degree,
                         active_sh_degree=sh_degree)


def _loss_alone_ms(height: int, width: int, repeats: int) -> float:
    import torch

    from gsgs_engine.train.losses import photometric_terms, total_loss

    g = torch.Generator().manual_seed(0)
    target = torch.rand(height, width, 3, generator=g)
    times = []
    for _ in range(repeats + 1):
        img = torch.rand(height, width, 3, generator=g).requires_grad_()
        t0 = time.perf_counter()
        total_loss(photometric_terms(img, target)).backward()
        times.append((time.perf_counter() - t0) * 1000)
    return statistics.median(times[1:])


def run_cell(scene_name: str, data: str, n: int, backend: str, steps: int, warmup: int, threads: int | None,
             seed: int) -> dict:
    """Measure one cell in this process (the parent runs each in a fresh subprocess)."""
    from pathlib import Path

    import torch

    from gsgs_engine.io.loader import load_scene
    from gsgs_engine.render import cpu_backend, select_backend
    from gsgs_engine.train.trainer import TrainConfig, Trainer

    if threads:
        torch.set_num_threads(threads)
    folder, kwargs = SCENES[scene_name]
    scene = load_scene(Path(data) / folder, **kwargs)
    select_backend(backend, torch.device("cpu"), torch.float32)  # loads (or builds) the extension first
    ops = cpu_backend._ops()
    clocks = hasattr(ops, "phase_seconds")  # a pinned older build has none
    config = TrainConfig(iters=10_000, backend=backend, seed=seed, sh_degree=3)
    trainer = Trainer(scene, config)
    model = synthetic_model(scene, trainer.train_views, n, seed)
    trainer.setup(initial_model=model)
    cam = trainer.train_views[0].camera
    for _ in range(warmup):
        trainer.train_step()
    if trainer.model.num_gaussians != n:
        raise GsgsError(f"the model changed size during the warm-up ({trainer.model.num_gaussians} != {n})")

    phases_before = dict(trainer.phase_seconds)
    if clocks:
        ops.reset_phase_seconds()
    times = []
    for _ in range(steps):
        t0 = time.perf_counter()
        trainer.train_step()
        times.append((time.perf_counter() - t0) * 1000)
    kernel = dict(zip(KERNEL_PHASES, (1000 * v / steps for v in ops.phase_seconds().tolist()) if clocks
                      else [float("nan")] * len(KERNEL_PHASES)))
    trainer_ms = {k: 1000 * (trainer.phase_seconds[k] - phases_before[k]) / steps for k in phases_before}
    k0 = {k: (0.0 if math.isnan(v) else v) for k, v in kernel.items()}
    profile = {
        "proj_fwd": kernel["proj_fwd"],
        "binning": kernel["binning"],
        "raster_fwd": kernel["raster_fwd"],
        "torch_fwd": trainer_ms["render"] - k0["proj_fwd"] - k0["binning"] - k0["raster_fwd"],
        "raster_bwd": kernel["bwd_prep"] + kernel["raster_bwd"] + kernel["bwd_reduce"],
        "proj_bwd": kernel["proj_bwd"],
        "torch_bwd": trainer_ms["backward"] - k0["bwd_prep"] - k0["raster_bwd"] - k0["bwd_reduce"] - k0["proj_bwd"],
        "optimiser": trainer_ms["optimise"],
        "densify": trainer_ms["densify"],
    }
    return {"scene": scene_name, "gaussians": n, "backend": backend, "width": cam.width, "height": cam.height,
            "views": len(trainer.train_views), "threads": torch.get_num_threads(), "steps": steps,
            "step_ms_median": round(statistics.median(times), 2), "step_ms_min": round(min(times), 2),
            "profile_ms": {k: round(v, 2) for k, v in profile.items()},
            "loss_alone_ms": round(_loss_alone_ms(cam.height, cam.width, 5), 2),
            "gaussians_after": trainer.model.num_gaussians}


def _run_cell_subprocess(spec: dict) -> dict:
    import os
    from pathlib import Path

    backend, _, tree = spec["backend"].partition("@")
    env = dict(os.environ)
    if tree:
        # This file runs as a script, so `import gsgs_engine` finds the pinned checkout first.
        env["PYTHONPATH"] = os.pathsep.join([str(Path(tree).resolve())] + [p for p in [env.get("PYTHONPATH")] if p])
        command = [sys.executable, str(Path(__file__).resolve()), "--cell", json.dumps({**spec, "backend": backend})]
    else:
        command = [sys.executable, "-m", "gsgs_engine.bench.train_step", "--cell", json.dumps(spec)]
    proc = subprocess.run(command, capture_output=True, text=True, env=env)
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        err = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {"scene": spec["scene"], "gaussians": spec["n"], "backend": spec["backend"], "error": err[:300]}
    return {**json.loads(lines[-1]), "backend": spec["backend"]}


def _parse(text: str, name: str) -> list[str]:
    values = [v.strip() for v in text.split(",") if v.strip()]
    if not values:
        raise GsgsError(f"--{name} is empty")
    return values


def markdown_tables(rows: list[dict], backends: list[str]) -> str:
    ok = [r for r in rows if "error" not in r]
    ratio = len(backends) >= 2  # the last backend against the first
    out = ["| scene | gaussians | " + " | ".join(f"{b} ms/step (median / min)" for b in backends)
           + (f" | speed-up {backends[-1]} vs {backends[0]} (median / min) |" if ratio else " |"),
           "|---|---:|" + "---:|" * len(backends) + ("---:|" if ratio else "")]
    cells = {(r["scene"], r["gaussians"], r["backend"]): r for r in ok}
    for scene, n in dict.fromkeys((r["scene"], r["gaussians"]) for r in rows):
        line = f"| {scene} | {n} |"
        found = [cells.get((scene, n, b)) for b in backends]
        for r in found:
            line += " - |" if r is None else f" {r['step_ms_median']:.1f} / {r['step_ms_min']:.1f} |"
        if ratio:
            old, new = found[0], found[-1]
            line += (f" {old['step_ms_median'] / new['step_ms_median']:.2f}x / {old['step_ms_min'] / new['step_ms_min']:.2f}x |"
                     if old and new else " - |")
        out.append(line)
    out += ["", "Profile, ms per step (averages over the timed steps; see the module docstring):", "",
            "| scene | gaussians | backend | " + " | ".join(PHASES) + " | loss alone |",
            "|---|---:|---|" + "---:|" * (len(PHASES) + 1)]
    for r in ok:
        p = r["profile_ms"]
        out.append(f"| {r['scene']} | {r['gaussians']} | {r['backend']} | "
                   + " | ".join("-" if math.isnan(p[k]) else f"{p[k]:.1f}" for k in PHASES)
                   + f" | {r['loss_alone_ms']:.1f} |")
    for r in rows:
        if "error" in r:
            out.append(f"\n{r['scene']} N={r['gaussians']} {r['backend']}: failed: {r['error']}")
    return "\n".join(out)


def run(args) -> int:
    from pathlib import Path

    scenes = _parse(args.scenes, "scenes")
    unknown = [s for s in scenes if s not in SCENES]
    if unknown:
        raise GsgsError(f"--scenes: unknown scene(s) {', '.join(unknown)}; choose from {', '.join(SCENES)}")
    for s in scenes:
        if not (Path(args.data) / SCENES[s][0]).exists():
            raise GsgsError(f"--data: {Path(args.data) / SCENES[s][0]} does not exist; point --data at the folder "
                            "holding llff_flower/ and blender_lego/")
    try:
        counts = [int(v) for v in _parse(args.counts, "counts")]
    except ValueError:
        raise GsgsError(f"--counts must be comma-separated integers (got {args.counts!r})") from None
    if min(counts) <= 0 or args.steps < 1 or args.warmup < 0:
        raise GsgsError("--counts must be positive, --steps at least 1 and --warmup at least 0")
    backends = _parse(args.backends, "backends")
    from gsgs_engine.render.api import available_backends

    status = available_backends()
    for spec in backends:
        b, _, tree = spec.partition("@")
        if tree and not (Path(tree) / "gsgs_engine").is_dir():
            raise GsgsError(f"--backends {spec}: {tree} is not a gsgs checkout (no gsgs_engine/ in it)")
        if tree:
            continue  # checked by the worker, in that checkout
        if b not in status or not status[b][0]:
            raise GsgsError(f"--backends: {b!r} is not usable here ({status.get(b, (False, 'unknown backend'))[1]})")

    print(f"gsgs bench train-step: {', '.join(backends)}; {args.steps} timed steps after {args.warmup}",
          file=sys.stderr, flush=True)
    rows = []
    for scene in scenes:
        for n in counts:
            for b in backends:
                spec = {"scene": scene, "data": str(args.data), "n": n, "backend": b, "steps": args.steps,
                        "warmup": args.warmup, "threads": args.threads, "seed": args.seed}
                row = _run_cell_subprocess(spec)
                rows.append(row)
                what = row.get("error") or f"{row['step_ms_median']:.1f} ms/step (min {row['step_ms_min']:.1f})"
                print(f"  {scene} N={n} {b}: {what}", file=sys.stderr, flush=True)
    print(markdown_tables(rows, backends))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


def _cell_main(argv: list[str]) -> int:
    from gsgs_engine.allocator import keep_freed_memory

    keep_freed_memory()  # the cell runs as every engine process does (the `gsgs` command line sets it)
    spec = json.loads(argv[argv.index("--cell") + 1])
    row = run_cell(spec["scene"], spec["data"], spec["n"], spec["backend"], spec["steps"], spec["warmup"],
                   spec["threads"], spec["seed"])
    print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":  # the per-cell worker: python -m gsgs_engine.bench.train_step --cell JSON
    sys.exit(_cell_main(sys.argv))
