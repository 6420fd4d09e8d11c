"""gsgs engine: Generative Sparse-view Gaussian Splatting, Blender-free.

The `io`, `job` and `cameras` layers import only the standard library and numpy, so
Blender's own Python can use them; everything else (torch, pycolmap, OpenCV, diffusers)
runs in a separate process started by the add-on or the `gsgs` command line.
"""

__version__ = "0.1.0"


class GsgsError(Exception):
    """An error a user can fix: the message names the file and what to do.

    The command line prints it as one line (no traceback) and exits with status 2.
    """
