"""Training checkpoints: written atomically (temp file + rename), the newest few kept.

A checkpoint holds everything a resumed run needs to continue the same schedule: step,
model, Adam state, densification statistics, RNG states, the plan and counters.
"""

from __future__ import annotations

import os
import re
import tempfile
from pathlib import Path

import torch

from gsgs_engine import GsgsError

_NAME = re.compile(r"^ckpt_(\d{7})\.pt$")
KEEP = 2


def checkpoint_path(directory: Path, step: int) -> Path:
    return Path(directory) / f"ckpt_{step:07d}.pt"


def list_checkpoints(directory: Path) -> list[tuple[int, Path]]:
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = []
    for entry in directory.iterdir():
        m = _NAME.match(entry.name)
        if m:
            found.append((int(m.group(1)), entry))
    return sorted(found)


def latest_checkpoint(directory: Path) -> Path | None:
    found = list_checkpoints(directory)
    return found[-1][1] if found else None


def to_cpu(obj):
    """`obj` with every tensor in its dicts, lists and tuples moved to the CPU (CPU tensors kept as they are)."""
    if isinstance(obj, torch.Tensor):
        return obj.detach().cpu() if obj.device.type != "cpu" else obj
    if isinstance(obj, dict):
        return {k: to_cpu(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(to_cpu(v) for v in obj)
    return obj


def save_checkpoint(directory: Path, step: int, state: dict, keep: int = KEEP) -> Path:
    """Write `state` for `step`; a crash mid-write leaves the previous checkpoint intact.

    Tensors are written as CPU tensors, so a checkpoint made on a GPU resumes on a CPU-only
    machine (and the other way round: the trainer moves what it loads to its own device).
    """
    state = to_cpu(state)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = checkpoint_path(directory, step)
    fd, tmp = tempfile.mkstemp(prefix=".ckpt.", suffix=".tmp", dir=directory)
    try:
        with os.fdopen(fd, "wb") as fh:
            torch.save(state, fh)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o644)  # mkstemp makes 0600; a checkpoint is an ordinary output file
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    for _, old in list_checkpoints(directory)[:-keep]:
        old.unlink(missing_ok=True)
    return path


def load_checkpoint(path: Path) -> dict:
    try:
        # weights_only=False: the state holds numpy RNG state and plain dicts we wrote ourselves
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # a truncated or foreign file
        raise GsgsError(f"{path}: unreadable checkpoint ({type(exc).__name__}: {exc}); "
                        "delete it to resume from the previous one, or train without --resume") from exc
