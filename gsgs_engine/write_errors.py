"""Write failures (read-only folder, a file where a folder should be, a full disk) as one clear error.

`writing(path, what)` wraps a write; `describe_os_error` words any OSError for the command
line's `gsgs: error:` line. Standard library only (job.py, which Blender imports, uses it).
"""

from __future__ import annotations

import contextlib
import errno
import os

from gsgs_engine import GsgsError

_FIX = {
    errno.EACCES: "no permission to write there; choose a folder you can write to",
    errno.EPERM: "no permission to write there; choose a folder you can write to",
    errno.EROFS: "the file system is read-only; choose a writable folder",
    errno.ENOSPC: "the disk is full; free space or choose another disk",
    errno.EDQUOT: "the disk quota is exhausted; free space or choose another disk",
    errno.ENOTDIR: "a file stands where a folder is needed; choose a folder path (or move that file)",
    errno.EEXIST: "a file stands where a folder is needed; choose a folder path (or move that file)",
    errno.EISDIR: "a folder stands where a file is needed",
}


def describe_os_error(exc: OSError, what: str | None = None) -> str:
    """'PATH: cannot write WHAT (reason); fix' for an OSError from writing WHAT, else 'PATH: reason; fix'."""
    path = os.fspath(exc.filename) if exc.filename is not None else "?"
    reason = exc.strerror or str(exc)
    fix = _FIX.get(exc.errno, "check the path and its permissions")
    return f"{path}: cannot write {what} ({reason}); {fix}" if what else f"{path}: {reason}; {fix}"


@contextlib.contextmanager
def writing(path, what: str):
    """Turn an OSError raised while writing `what` to `path` into a GsgsError naming them."""
    try:
        yield
    except OSError as exc:
        name = os.path.basename(os.fspath(exc.filename)) if exc.filename is not None else ""
        if exc.filename is None or name.startswith(f".{os.path.basename(os.fspath(path))}."):
            exc.filename = os.fspath(path)  # the temp file of an atomic write: name the real target
        raise GsgsError(describe_os_error(exc, what)) from None


@contextlib.contextmanager
def sigterm_interrupts():
    """While inside, SIGTERM raises KeyboardInterrupt (as Ctrl-C does), so `finally` blocks run: a
    command's status.json says cancelled and child processes (the pycolmap worker) are stopped.
    The trainer installs its own handler while it trains (finish the step, checkpoint) and restores
    this one after. A no-op off the main thread."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _raise(signum, frame):
        raise KeyboardInterrupt(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)
