"""gsgs engine: Generative Sparse-view Gaussian Splatting, Blender-free.

The `io`, `job` and `cameras` layers import only the standard library and numpy, so
Blender's own Python can use them; everything else (torch, pycolmap, OpenCV, diffusers)
runs in a separate process started by the add-on or the `gsgs` command line.
"""

import os
from pathlib import Path

__version__ = "0.1.0"

# Idle OpenMP workers sleep instead of spinning. libgomp reads this when torch loads, and
# every engine entry point (CLI, job runner, benchmark cells) imports this package first.
# Measured on the shared 2-core machine with other jobs running: a lego_200 training step
# took 1.5 s with spinning workers and 0.15 s with passive ones (2 threads each); on an idle
# machine the two are within noise. A user's own setting wins.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def user_cache_dir(name: str) -> Path:
    """$XDG_CACHE_HOME/gsgs/NAME, else ~/.cache/gsgs/NAME: where gsgs keeps what it can make again (the compiled
    kernel, LPIPS weights, the init cache)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")) / "gsgs" / name


class GsgsError(Exception):
    """An error a user can fix: the message names the file and what to do.

    The command line prints it as one line (no traceback) and exits with status 2.
    """
