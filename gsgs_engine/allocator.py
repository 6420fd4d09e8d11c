"""Keep freed memory inside the engine's process instead of handing it back to the system at every step.

A training step allocates and frees the same few image- and Gaussian-sized tensors (megabytes each) again and again.
glibc's malloc returns large freed blocks to the kernel (munmap, or trimming the top of the heap), and the next
step's allocation of the same size takes fresh pages, which the kernel must fault in and zero: on the 2-core test
machine that was 7.7 % of a NeRF-synthetic auto run's CPU time in the kernel, against 0.8 % with the two
thresholds below (perf, one thread; docs/speed.md). Raising them makes malloc keep and reuse that memory: the
process stays at its peak size instead of shrinking between steps, and nothing else changes (results are
bit-identical).

Applied once by the `gsgs` command line (every engine process: training, jobs, benchmarks) and by the benchmarks' cell
workers (`python -m gsgs_engine.bench.rasterizer / train_step / accuracy_cell`), which time what the command line
runs; a no-op where the C library is not glibc. GSGS_MALLOC_TUNING=0 leaves malloc's defaults.
"""

from __future__ import annotations

import ctypes
import os
import sys

M_TRIM_THRESHOLD = -1  # glibc's mallopt parameter numbers (malloc.h)
M_MMAP_THRESHOLD = -3
TRIM_THRESHOLD = 1 << 30  # keep up to 1 GiB of freed memory at the top of the heap
MMAP_THRESHOLD = 64 << 20  # blocks under 64 MiB come from the heap (reused), not from their own mapping


def keep_freed_memory() -> bool:
    """Set the two malloc thresholds (glibc); True when both were set."""
    if sys.platform != "linux" or os.environ.get("GSGS_MALLOC_TUNING", "1") == "0":
        return False
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):  # musl, or no glibc by that name: its defaults stay
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    # Both or neither: a fixed trim threshold alone also fixes the mmap threshold at its 128 KiB default, and every
    # image-sized block would then be mapped and unmapped at each step (3x slower in a synthetic loop).
    return mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD) == 1 and mallopt(M_TRIM_THRESHOLD, TRIM_THRESHOLD) == 1
