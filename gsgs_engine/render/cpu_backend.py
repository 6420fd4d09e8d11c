"""The compiled CPU rasteriser: a C++ torch extension with 3DGS's exact tile rasterisation.

`rasterize_cpu` has the semantics of `reference.rasterize_reference` (same arguments, same
outputs, gradients for means2d, conics, colors, opacities, depths and background) and runs tiles
in parallel on torch's threads (`torch.get_num_threads()`). The kernel is float32 only; the
`render()` dispatcher falls back to the reference for float64 inputs.

The extension is built once into a folder keyed by a hash of its sources, the compile flags and
the torch / Python versions (`~/.cache/gsgs/torch_extensions/<hash>`, or `$GSGS_BUILD_DIR/<hash>`),
so later imports load the built library without compiling. `python -m gsgs_engine build-ext`
builds it at set-up time.
"""

from __future__ import annotations

import functools
import hashlib
import os
import sys
import threading
import time
from pathlib import Path

from gsgs_engine import GsgsError, user_cache_dir

CSRC = Path(__file__).resolve().parent / "csrc"
SOURCES = ("rasterize_cpu.cpp", "project_cpu.cpp", "ssim_cpu.cpp", "binocular_cpu.cpp")
# Plain -O3: no -ffast-math (NaN/inf handling and the exact 3DGS thresholds must hold) and no
# -march=native (a cached build must run on any x86-64; the kernel carries its own AVX2 clone).
# -ffp-contract=off keeps forward and backward evaluating alpha bit-identically; only the tile bodies' AVX2+FMA
# variant contracts (see rasterize_cpu.cpp, tile_kernels).
CFLAGS = ("-O3", "-ffp-contract=off", "-fno-math-errno", "-fno-trapping-math", "-fopenmp")
# at::parallel_for is header-inline (`#pragma omp parallel` in ATen/ParallelOpenMP.h): without
# -fopenmp it compiles to a serial loop and a second thread buys nothing. The library links the
# soname libgomp.so.1, which resolves to the copy torch has already loaded (one OpenMP runtime).
LDFLAGS = ("-fopenmp",)
_OP_NAMESPACE = "gsgs_raster_cpu"
_READY_MARKER = "gsgs_build_ok"
_STALE_LOCK_S = 20 * 60

_lock = threading.Lock()
_state: dict = {}  # "ops" -> torch.ops namespace, or "error" -> reason (one attempt per process)


@functools.lru_cache(maxsize=1)
def _source_hash() -> str:
    import platform

    import torch

    h = hashlib.sha256()
    for name in SOURCES:
        h.update(name.encode())
        h.update((CSRC / name).read_bytes())
    for header in sorted(CSRC.glob("*.h")):
        h.update(header.name.encode())
        h.update(header.read_bytes())
    h.update(" ".join(CFLAGS + LDFLAGS).encode())
    h.update(torch.__version__.encode())
    h.update(sys.version.encode())
    h.update(f"{sys.platform} {platform.machine()}".encode())  # a home folder shared across machines
    return h.hexdigest()[:16]


def build_dir() -> Path:
    """Where the extension is (or will be) built; one folder per source/torch hash."""
    root = os.environ.get("GSGS_BUILD_DIR")
    if root:
        base = Path(root).expanduser()
    else:
        base = user_cache_dir("torch_extensions")
    return base / _source_hash()


def _library_name() -> str:
    return f"gsgs_rasterize_cpu_{_source_hash()}"


def _summarise_build_error(exc: BaseException) -> str:
    """The compiler's first error lines (the full log is in the exception / build folder)."""
    text = str(exc)
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    compiler = [line for line in lines if "error:" in line.lower()]  # "file:line:col: error: ..."
    other = [line for line in lines if "error" in line.lower() and not line.startswith("[")]
    picked = compiler[:2] or other[:2] or lines[-2:]
    return " | ".join(picked)[:600] or type(exc).__name__


def _compile(verbose: bool = False) -> None:
    """Compile with torch.utils.cpp_extension into build_dir() and load the library."""
    import torch
    from torch.utils import cpp_extension

    directory = build_dir()
    directory.mkdir(parents=True, exist_ok=True)
    # cpp_extension runs `ninja` from PATH; the venv's own bin (where pip puts ninja) may not be on it.
    path_entries = os.environ.get("PATH", "").split(os.pathsep)
    extra = [str(Path(sys.executable).parent)]
    try:
        import ninja  # the pip package; BIN_DIR holds the executable

        extra.append(str(ninja.BIN_DIR))
    except (ImportError, AttributeError):
        pass
    missing = [p for p in extra if p not in path_entries]
    if missing:
        os.environ["PATH"] = os.pathsep.join(missing + path_entries)
    if not cpp_extension.is_ninja_available():
        raise RuntimeError("ninja is not installed (pip install ninja)")
    # A build killed outright (not interrupted) leaves cpp_extension's lock behind, and every later
    # build would wait on it forever; no build takes anywhere near this long.
    lock = directory / "lock"
    if lock.exists() and time.time() - lock.stat().st_mtime > _STALE_LOCK_S:
        lock.unlink(missing_ok=True)
    cpp_extension.load(
        name=_library_name(),
        sources=[str(CSRC / name) for name in SOURCES],
        extra_cflags=list(CFLAGS),
        extra_ldflags=list(LDFLAGS),
        build_directory=str(directory),
        is_python_module=False,
        verbose=verbose,
    )
    (directory / _READY_MARKER).write_text(torch.__version__ + "\n")


def is_built() -> bool:
    """True when a finished build for these sources and this torch exists (nothing to compile)."""
    directory = build_dir()
    return (directory / f"{_library_name()}.so").exists() and (directory / _READY_MARKER).exists()


def _load(verbose: bool = False, announce: bool = False):
    """The torch.ops namespace of the extension, building it when needed (raises on failure)."""
    import torch

    if is_built():
        try:
            torch.ops.load_library(str(build_dir() / f"{_library_name()}.so"))
            return getattr(torch.ops, _OP_NAMESPACE)
        except OSError:  # a damaged or foreign library file: build it again below
            (build_dir() / _READY_MARKER).unlink(missing_ok=True)
            (build_dir() / f"{_library_name()}.so").unlink(missing_ok=True)
    if announce:
        print(f"gsgs: compiling the CPU rasteriser into {build_dir()} (first use only, about a minute)",
              file=sys.stderr, flush=True)
    _compile(verbose=verbose)
    return getattr(torch.ops, _OP_NAMESPACE)


def _ops():
    with _lock:
        if "ops" not in _state and "error" not in _state:
            try:
                _state["ops"] = _load(announce=True)
            except Exception as exc:  # compiler missing, build error, ABI mismatch: reported, not fatal
                _state["error"] = (f"{_summarise_build_error(exc)} (build folder {build_dir()}; "
                                   "GSGS_BUILD_DIR moves it)")
        return _state.get("ops")


def available() -> bool:
    """True when the compiled rasteriser builds and loads (tried once per process)."""
    return _ops() is not None


def unavailable_reason() -> str | None:
    """Why the extension is unavailable (a compiler error summary), or None when it works."""
    _ops()
    return _state.get("error")


#: the compiled kernel's phase clocks, in the order `gsgs_raster_cpu::phase_seconds` returns them
PHASES = ("project_forward", "binning", "raster_forward", "backward_prep", "raster_backward", "backward_reduce",
          "project_backward")


def phase_seconds() -> dict[str, float] | None:
    """Seconds the kernel has spent per phase in this process so far, or None while it is not loaded (its clocks
    only run once it is; loading is not attempted here)."""
    ops = _state.get("ops")
    if ops is None or not hasattr(ops, "phase_seconds"):
        return None
    return dict(zip(PHASES, ops.phase_seconds().tolist()))


def _check_inputs(means2d, conics, colors, opacities, depths, radii, background) -> None:
    import torch

    tensors = {"means2d": means2d, "conics": conics, "colors": colors, "opacities": opacities,
               "depths": depths, "background": background}
    for name, t in tensors.items():
        if not isinstance(t, torch.Tensor):
            raise GsgsError(f"rasterize_cpu: {name} must be a torch tensor, got {type(t).__name__}")
        if t.device.type != "cpu":
            raise GsgsError(f"rasterize_cpu: {name} is on {t.device}; the cpu backend needs CPU tensors (use backend='cuda')")
        if t.dtype != torch.float32:
            raise GsgsError(f"rasterize_cpu: {name} is {t.dtype}; the compiled kernel is float32 only (use backend='reference' for float64)")
    n = means2d.shape[0]
    shapes = {"means2d": (means2d, (n, 2)), "conics": (conics, (n, 3)), "colors": (colors, (n, 3)),
              "opacities": (opacities, (n,)), "depths": (depths, (n,)), "radii": (radii, (n,)),
              "background": (background, (3,))}
    for name, (t, shape) in shapes.items():
        if tuple(t.shape) != shape:
            raise GsgsError(f"rasterize_cpu: {name} has shape {tuple(t.shape)}, expected {shape}")


@functools.lru_cache(maxsize=1)
def _function():
    import torch

    class RasterizeCpu(torch.autograd.Function):
        @staticmethod
        def forward(ctx, means2d, conics, colors, opacities, depths, radii, width, height, background, absgrad):
            ops = _ops()
            (color, depth, alpha, final_T, last, tile_offsets, tile_ranks, entry_slots, order, slot_offset,
             splats) = ops.forward(means2d, conics, colors, opacities, depths, radii, width, height, background)
            ctx.size = (width, height)
            ctx.absgrad = bool(absgrad)
            ctx.save_for_backward(means2d, conics, colors, opacities, depths, radii, background, final_T, last,
                                  tile_offsets, tile_ranks, entry_slots, order, slot_offset, splats)
            return color, depth, alpha

        @staticmethod
        @torch.autograd.function.once_differentiable
        def backward(ctx, grad_color, grad_depth, grad_alpha):
            (means2d, conics, colors, opacities, depths, radii, background, final_T, last, tile_offsets,
             tile_ranks, entry_slots, order, slot_offset, splats) = ctx.saved_tensors
            width, height = ctx.size

            def dense(grad, shape):
                if grad is None:
                    return torch.zeros(shape, dtype=torch.float32)
                return grad.to(torch.float32).contiguous()

            grad_color = dense(grad_color, (height, width, 3))
            grad_depth = dense(grad_depth, (height, width))
            grad_alpha = dense(grad_alpha, (height, width))
            g_means, g_conics, g_colors, g_opac, g_depths, g_abs = _ops().backward(
                means2d, conics, colors, opacities, depths, radii, width, height, background, final_T, last,
                tile_offsets, tile_ranks, entry_slots, order, slot_offset, splats, grad_color, grad_depth, grad_alpha,
                ctx.absgrad)
            if ctx.absgrad:
                # AbsGS's statistic, where gsplat puts it: the saved input is the caller's own tensor object
                means2d.absgrad = g_abs
            g_background = None
            if ctx.needs_input_grad[8]:
                # colour = ... + T_final * background
                g_background = (grad_color * final_T.unsqueeze(-1)).sum(dim=(0, 1))
            return g_means, g_conics, g_colors, g_opac, g_depths, None, None, None, g_background, None

    return RasterizeCpu


def rasterize_cpu(means2d, conics, colors, opacities, depths, radii, width: int, height: int, background,
                  absgrad: bool = False):
    """Rasterise projected Gaussians -> (color [H,W,3], depth [H,W], alpha [H,W]); differentiable.

    Same arguments and semantics as `rasterize_reference`: depth is sum(z_i alpha_i T_i) (not
    divided by alpha), alpha = 1 - final transmittance, Gaussians with radius 0 are ignored.
    float32 CPU tensors only. Deterministic: the result does not depend on the thread count.

    absgrad: the backward also sets `means2d.absgrad` [N, 2], the sums over pixels of each pixel's own
    |dL/dmeans2d| per axis (AbsGS; gsplat's attribute of the same name), for densifying by it.
    """
    import torch

    _check_inputs(means2d, conics, colors, opacities, depths, radii, background)
    width, height = int(width), int(height)
    if width <= 0 or height <= 0:
        raise GsgsError(f"rasterize_cpu: image size must be positive, got {width}x{height}")
    if not available():
        raise GsgsError(f"the compiled CPU rasteriser is unavailable ({unavailable_reason()}); "
                        "run `python -m gsgs_engine build-ext` to see the build log, or use backend='reference'")
    if absgrad and not means2d.is_contiguous():  # .contiguous() would copy it, and the statistic land on the copy
        raise GsgsError("rasterize_cpu: absgrad needs a contiguous means2d (it is set on the tensor passed in)")
    radii = radii.detach().to(torch.int32).contiguous()
    return _function().apply(means2d.contiguous(), conics.contiguous(), colors.contiguous(),
                             opacities.contiguous(), depths.contiguous(), radii, width, height,
                             background.contiguous(), bool(absgrad))


# -- `python -m gsgs_engine build-ext` -----------------------------------------------------------
def add_arguments(parser) -> None:
    parser.add_argument("--force", action="store_true", help="delete the cached build and compile again")
    parser.add_argument("--verbose", action="store_true", help="show the compiler commands and output")


def run(args) -> int:
    import shutil

    directory = build_dir()
    if args.force and directory.exists():
        shutil.rmtree(directory)
    reused = is_built()
    start = time.perf_counter()
    try:
        _load(verbose=args.verbose)
    except Exception as exc:
        print(f"gsgs: building the CPU rasteriser in {directory} failed: {_summarise_build_error(exc)}", file=sys.stderr)
        print("gsgs: the reference rasteriser will be used (slower); rerun with --verbose for the full log",
              file=sys.stderr)
        return 1
    seconds = time.perf_counter() - start
    what = "loaded the existing build" if reused else "built"
    print(f"gsgs: CPU rasteriser {what} in {directory} ({seconds:.1f} s)")
    return 0
