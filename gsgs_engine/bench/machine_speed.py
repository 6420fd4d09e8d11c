"""`gsgs bench machine`: this machine's speed on one fixed render, for the add-on's training-time estimate.

The workload is the rasterizer benchmark's synthetic scene (gsgs_engine.bench.rasterizer.make_scene: PROBE_GAUSSIANS
Gaussians, SH degree 3, a PROBE_SIDE-pixel square camera, seed 0) rendered and back-propagated on the compiled CPU
kernel at torch's thread count, as a training job would run: the median of PROBE_REPEATS timed runs after one
warm-up, printed as one JSON line. It takes about a second after torch has loaded.

The add-on divides it by the same probe's time on the machine and day its reference training cells were measured
(gsgs_blender/train_estimate.py, PROBE_REFERENCE_MS), so its first estimate on a new machine, or on a slow day of a
shared one, follows the machine instead of the reference's. It never compiles the kernel (minutes): without a
built kernel it prints a JSON line with "error" and exits 3, and the estimate goes unprobed.

Both lines also say whether a job set to Device "auto" would train on a GPU here: "cuda" holds the CUDA device's
name where torch sees one and gsplat imports (the CUDA backend's own check), else null; the add-on then states a
GPU estimate (train_estimate.job_device).
"""

from __future__ import annotations

import json
import statistics
import sys
import time

PROBE_GAUSSIANS = 30000
PROBE_SIDE = 256
PROBE_REPEATS = 7


def add_arguments(parser) -> None:
    parser.add_argument("--repeats", type=int, default=PROBE_REPEATS,
                        help=f"timed renders; the median is reported (default {PROBE_REPEATS})")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice, "
                        "as a training job)")


def probe(repeats: int = PROBE_REPEATS, threads: int | None = None) -> dict:
    """{"probe_ms": median forward+backward ms, "threads", "gaussians", "side", "repeats"} (raises GsgsError
    when the compiled kernel is not built)."""
    import torch

    from gsgs_engine import GsgsError
    from gsgs_engine.bench.rasterizer import SH_DEGREE, make_scene
    from gsgs_engine.render import cpu_backend, render

    if repeats < 1:
        raise GsgsError("--repeats must be at least 1")
    if not cpu_backend.is_built():
        raise GsgsError("the compiled CPU kernel is not built yet (it builds at the first training job, or "
                        "`python -m gsgs_engine build-ext`); the machine was not probed")
    if threads:
        torch.set_num_threads(threads)
    tensors, camera = make_scene(PROBE_GAUSSIANS, PROBE_SIDE, seed=0)
    leaves = [t.requires_grad_() for t in tensors]
    background = torch.ones(3)

    def once() -> float:
        t0 = time.perf_counter()
        out = render(*leaves, camera, SH_DEGREE, background, backend="cpu")
        (out.color.sum() + out.alpha.sum()).backward()
        for leaf in leaves:
            leaf.grad = None
        return (time.perf_counter() - t0) * 1000.0

    once()  # loads the kernel, warms the caches
    ms = statistics.median(once() for _ in range(repeats))
    return {"probe_ms": round(ms, 3), "threads": torch.get_num_threads(), "gaussians": PROBE_GAUSSIANS,
            "side": PROBE_SIDE, "repeats": repeats}


def cuda_device() -> str | None:
    """The CUDA device gsplat would train on here (its name), or None (no CUDA device, or gsplat does not import)."""
    import torch

    from gsgs_engine.render import cuda_backend

    return torch.cuda.get_device_name(0) if cuda_backend.available() else None


def run(args) -> int:
    from gsgs_engine import GsgsError

    gpu = cuda_device()
    try:
        result = probe(args.repeats, args.threads)
    except GsgsError as exc:
        print(json.dumps({"error": str(exc), "cuda": gpu}), flush=True)
        return 3
    result["cuda"] = gpu
    print(json.dumps(result), flush=True)
    print(f"gsgs bench machine: {result['probe_ms']:.1f} ms for a {result['gaussians']}-Gaussian "
          f"{result['side']} px render with backward on {result['threads']} thread(s)", file=sys.stderr)
    return 0
