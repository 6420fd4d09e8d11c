"""`gsgs bench rasterizer`: forward / forward+backward time and peak memory per backend.

Each (backend, Gaussians, resolution) cell runs in its own subprocess so that its peak
resident memory is its own: peak_mb is the growth of ru_maxrss (resident set high-water
mark, getrusage) from just after the scene is built to the end of the timed runs, i.e. the
extra host memory rendering needs, including torch's caching. On CUDA it is
torch.cuda.max_memory_allocated() above the memory the scene itself holds. Times are
medians over --repeats runs after one warm-up; forward runs with autograd recording (as in
training). The scene: means uniform in [-1, 1]^3, seen whole by a square camera 4 units
away (fx = width); log-uniform scales in [0.005, 0.03]; random rotations; opacities in
[0.1, 0.9]; SH degree 3 (16 coefficients per channel).
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
import time

from gsgs_engine import GsgsError

DEFAULT_SIZES = "1000,10000,50000,100000"
DEFAULT_RESOLUTIONS = "200,800"
SH_DEGREE = 3


def add_arguments(parser) -> None:
    parser.add_argument("--json", metavar="FILE", help="also write the rows as a JSON list to FILE")
    parser.add_argument("--sizes", default=DEFAULT_SIZES, help=f"Gaussian counts (default {DEFAULT_SIZES})")
    parser.add_argument("--resolutions", default=DEFAULT_RESOLUTIONS,
                        help=f"square image sides in pixels (default {DEFAULT_RESOLUTIONS})")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs per cell; the median is reported")
    parser.add_argument("--backends", default=None,
                        help="comma-separated subset of reference,cpu,cuda (default: every available one)")
    parser.add_argument("--budget-s", type=float, default=120.0,
                        help="per-cell time budget; a cell expected to exceed it is skipped (default 120)")
    parser.add_argument("--threads", default=None,
                        help="torch CPU threads, or a comma-separated list (e.g. 1,2: every cell at each count, "
                             "side by side, with the speed-up over the first); default: torch's choice")
    parser.add_argument("--seed", type=int, default=0)


def _parse_list(text: str, name: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise GsgsError(f"--{name} must be comma-separated integers (got {text!r})") from None
    if not values or min(values) <= 0:
        raise GsgsError(f"--{name} needs positive integers (got {text!r})")
    return values


def make_scene(n: int, resolution: int, seed: int, device: str = "cpu"):
    """Random benchmark scene and a camera that sees all of it."""
    import numpy as np
    import torch

    from gsgs_engine.cameras import Camera

    g = torch.Generator().manual_seed(seed)
    means = torch.rand(n, 3, generator=g) * 2 - 1
    quats = torch.randn(n, 4, generator=g)
    scales = torch.exp(torch.empty(n, 3).uniform_(math.log(0.005), math.log(0.03), generator=g))
    opacities = torch.rand(n, generator=g) * 0.8 + 0.1
    sh = torch.randn(n, (SH_DEGREE + 1) ** 2, 3, generator=g) * 0.2
    sh[:, 0] = (torch.rand(n, 3, generator=g) - 0.5) / 0.28209479177387814
    camera = Camera(R=np.eye(3), t=np.array([0.0, 0.0, 4.0]), fx=resolution, fy=resolution,
                    cx=resolution / 2, cy=resolution / 2, width=resolution, height=resolution)
    tensors = [t.to(device) for t in (means, quats, scales, opacities, sh)]
    return tensors, camera


def _max_rss_mb() -> float:
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux reports KiB


def run_cell(backend: str, n: int, resolution: int, repeats: int, budget_s: float, seed: int,
             threads: int | None) -> dict:
    """Measure one cell in this process (the parent runs it in a fresh subprocess)."""
    import statistics

    import torch

    from gsgs_engine.render import render, select_backend

    if threads:
        torch.set_num_threads(threads)
    device = "cuda" if backend == "cuda" else "cpu"
    tensors, camera = make_scene(n, resolution, seed, device)
    leaves = [t.clone().requires_grad_() for t in tensors]
    background = torch.ones(3, device=device)
    row = {"backend": backend, "gaussians": n, "width": resolution, "height": resolution,
           "sh_degree": SH_DEGREE, "threads": torch.get_num_threads()}

    def sync():
        if device == "cuda":
            torch.cuda.synchronize()

    def forward():
        return render(*leaves, camera, SH_DEGREE, background, backend=backend)

    def forward_backward():
        out = forward()
        (out.color.sum() + out.depth.sum() + out.alpha.sum()).backward()
        for leaf in leaves:
            leaf.grad = None

    # Resolve the backend first: for "cpu" this loads (or, after a source change, compiles) the
    # extension, which must not be counted as rendering time.
    select_backend(backend, torch.device(device), torch.float32)
    if device == "cuda":
        torch.cuda.synchronize()
        base_alloc = torch.cuda.memory_allocated()
        torch.cuda.reset_peak_memory_stats()
    rss_before = _max_rss_mb()

    start = time.perf_counter()
    forward_backward()  # warm-up (also loads kernels), not timed
    sync()
    warm = time.perf_counter() - start
    if warm > budget_s:
        row.update(forward_ms=None, forward_backward_ms=None, peak_mb=None,
                   note=f"skipped: over budget (warm-up alone took {warm:.0f} s > {budget_s:.0f} s)")
        return row

    # Timed runs stop early once the budget is spent; the median is then over fewer runs,
    # and the note says so.
    fwd, fwd_bwd = [], []
    start = time.perf_counter()
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = forward()
        sync()
        fwd.append((time.perf_counter() - t0) * 1000)
        del out
        t0 = time.perf_counter()
        forward_backward()
        sync()
        fwd_bwd.append((time.perf_counter() - t0) * 1000)
        if time.perf_counter() - start > budget_s:
            break
    note = "" if len(fwd) == repeats else f"median of {len(fwd)} of {repeats} runs (budget reached)"
    if device == "cuda":
        peak = (torch.cuda.max_memory_allocated() - base_alloc) / 2 ** 20
    else:
        peak = _max_rss_mb() - rss_before
    row.update(forward_ms=round(statistics.median(fwd), 3), forward_backward_ms=round(statistics.median(fwd_bwd), 3),
               peak_mb=round(peak, 1), note=note)
    return row


def _run_cell_subprocess(backend, n, resolution, repeats, budget_s, seed, threads) -> dict:
    spec = json.dumps({"backend": backend, "n": n, "resolution": resolution, "repeats": repeats,
                       "budget_s": budget_s, "seed": seed, "threads": threads})
    base = {"backend": backend, "gaussians": n, "width": resolution, "height": resolution,
            "forward_ms": None, "forward_backward_ms": None, "peak_mb": None}
    # The worker stops itself after a warm-up over budget, or at the first timed run past it;
    # this hard limit catches a single run that is itself far too slow (plus start-up time).
    limit = budget_s * 3 + 60
    try:
        proc = subprocess.run([sys.executable, "-m", "gsgs_engine.bench.rasterizer", "--cell", spec],
                              capture_output=True, text=True, timeout=limit)
    except subprocess.TimeoutExpired:
        return {**base, "note": f"skipped: over budget (killed after {limit:.0f} s)"}
    lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
    if proc.returncode != 0 or not lines:
        err = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return {**base, "note": f"failed: {err[:200]}"}
    return json.loads(lines[-1])


def _fmt(value, digits=1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def markdown_table(rows: list[dict]) -> str:
    lines = ["| backend | gaussians | resolution | threads | forward ms | fwd+bwd ms | peak MB | "
             "speed-up vs reference (fwd+bwd) | speed-up vs the first thread count | note |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        threads = "-" if r.get("threads") is None else r["threads"]
        lines.append(f"| {r['backend']} | {r['gaussians']} | {r['width']}x{r['height']} | {threads} | "
                     f"{_fmt(r['forward_ms'])} | {_fmt(r['forward_backward_ms'])} | {_fmt(r['peak_mb'])} | "
                     f"{_fmt(r.get('speedup_vs_reference'), 2)} | {_fmt(r.get('speedup_vs_first_threads'), 2)} | "
                     f"{r.get('note', '')} |")
    return "\n".join(lines)


def run(args) -> int:
    from gsgs_engine.render.api import available_backends

    sizes = _parse_list(args.sizes, "sizes")
    resolutions = _parse_list(args.resolutions, "resolutions")
    if args.repeats < 1:
        raise GsgsError("--repeats must be at least 1")
    status = available_backends()
    if args.backends:
        wanted = [b.strip() for b in args.backends.split(",") if b.strip()]
        unknown = [b for b in wanted if b not in status]
        if unknown:
            raise GsgsError(f"--backends: unknown backend(s) {', '.join(unknown)}; choose from {', '.join(status)}")
    else:
        wanted = list(status)
    backends = []
    for b in wanted:
        ok, reason = status[b]
        if ok:
            backends.append(b)
        else:
            print(f"gsgs bench: skipping backend {b!r}: {reason}", file=sys.stderr)
    if not backends:
        raise GsgsError("no rasteriser backend is available to benchmark")

    thread_counts = [None] if args.threads in (None, "") else _parse_list(str(args.threads), "threads")
    print(f"gsgs bench rasterizer: backends {', '.join(backends)}; SH degree {SH_DEGREE}; median of {args.repeats}; "
          f"per-cell budget {args.budget_s:.0f} s", file=sys.stderr)
    rows = []
    over_budget: dict[tuple, list[tuple[int, int]]] = {(b, t): [] for b in backends for t in thread_counts}
    for resolution in sorted(resolutions):
        for n in sorted(sizes):
            for b, threads in ((b, t) for b in backends for t in thread_counts):
                if any(n >= n0 and resolution >= r0 for n0, r0 in over_budget[b, threads]):
                    # cost grows with both: no need to spend the budget finding out again
                    row = {"backend": b, "gaussians": n, "width": resolution, "height": resolution,
                           "forward_ms": None, "forward_backward_ms": None, "peak_mb": None,
                           "note": "skipped: over budget (a smaller cell already was)"}
                else:
                    row = _run_cell_subprocess(b, n, resolution, args.repeats, args.budget_s, args.seed, threads)
                if row.get("note", "").startswith("skipped: over budget"):
                    over_budget[b, threads].append((n, resolution))
                row.setdefault("threads", threads)
                print(f"  {b:9s} N={n:<7d} {resolution}x{resolution} threads {row['threads']}: "
                      f"fwd {_fmt(row['forward_ms'])} ms, "
                      f"fwd+bwd {_fmt(row['forward_backward_ms'])} ms, peak {_fmt(row['peak_mb'])} MB "
                      f"{row.get('note', '')}", file=sys.stderr, flush=True)
                rows.append(row)
    reference = {(r["gaussians"], r["width"], r["threads"]): r["forward_backward_ms"]
                 for r in rows if r["backend"] == "reference"}
    first = {(r["backend"], r["gaussians"], r["width"]): r["forward_backward_ms"]
             for r in reversed(rows) if r["threads"] == thread_counts[0]}
    for r in rows:
        ref = reference.get((r["gaussians"], r["width"], r["threads"]))
        mine = r["forward_backward_ms"]
        r["speedup_vs_reference"] = round(ref / mine, 2) if ref and mine else None
        base = first.get((r["backend"], r["gaussians"], r["width"]))
        r["speedup_vs_first_threads"] = (round(base / mine, 2) if len(thread_counts) > 1 and base and mine
                                         else None)
    print(markdown_table(rows))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


def _cell_main(argv: list[str]) -> int:
    from gsgs_engine.allocator import keep_freed_memory

    keep_freed_memory()  # the cell runs as every engine process does (the `gsgs` command line sets it)
    spec = json.loads(argv[argv.index("--cell") + 1])
    row = run_cell(spec["backend"], spec["n"], spec["resolution"], spec["repeats"], spec["budget_s"], spec["seed"],
                   spec["threads"])
    print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":  # the per-cell worker: python -m gsgs_engine.bench.rasterizer --cell JSON
    sys.exit(_cell_main(sys.argv))
