"""A run folder belongs to one run.

`claim_run_folder` is called before a new `gsgs train` writes anything: a folder that holds
another run's checkpoints or results is refused unless the user resumes it (`--resume`) or
replaces it (`--overwrite`, which removes exactly the files a run writes, nothing else).

`scene_fingerprint` identifies the training data (view names, cameras, image sizes and a
coarse colour signature); a checkpoint stores it with its settings, and `check_resume`
refuses to continue a checkpoint on other data or with other settings, naming what differs.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np

from gsgs_engine import GsgsError

RESULT_FILES = ("metrics.json", "point_cloud.ply", "progress.jsonl", "eval.json", "log.txt", "status.json",
                "background_sphere.png")  # the last: train/background_sphere.TEXTURE_FILE (a run with the sphere)
RESULT_DIRS = ("checkpoints", "renders", "pseudo")
# settings a resumed run may choose anew: the schedule length (the checkpoint's wins), where it runs,
# how often it checkpoints, and how the (already made) initial model would have been made
RESUME_MAY_DIFFER = ("iters", "backend", "checkpoint_every", "init", "min_init_points", "random_init_points")


def previous_run(out: Path) -> list[str]:
    """What in `out` belongs to an earlier run (names relative to `out`); empty when nothing does."""
    out = Path(out)
    found = []
    ckpts = out / "checkpoints"
    if ckpts.is_dir() and any(p.name.startswith("ckpt_") for p in ckpts.iterdir()):
        found.append("checkpoints/")
    for name in ("metrics.json", "point_cloud.ply", "progress.jsonl"):
        if (out / name).exists():
            found.append(name)
    return found


def clear_run_outputs(out: Path) -> None:
    """Remove the files and folders a run writes into `out` (and only those)."""
    out = Path(out)
    for name in RESULT_FILES:
        (out / name).unlink(missing_ok=True)
    for name in RESULT_DIRS:
        if (out / name).is_dir():
            shutil.rmtree(out / name)


def claim_run_folder(out: Path, resume: bool, overwrite: bool, has_checkpoint: bool) -> None:
    """Make `out` this run's folder, or raise GsgsError saying how to proceed."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise GsgsError(f"{out}: --out names a file, not a folder; choose a folder path for the run's outputs")
    if resume and has_checkpoint:
        return  # continuing the run that is there; check_resume verifies it is the same run
    found = previous_run(out)
    if not found:
        return
    if overwrite:
        clear_run_outputs(out)
        return
    why = "--resume found no checkpoint to continue, and the folder " if resume else ""
    raise GsgsError(f"{out}: {why}holds another run ({', '.join(found)}); continue that run with --resume, replace "
                    "it with --overwrite, or choose another --out folder")


def scene_fingerprint(train_views, targets) -> dict:
    """Names, cameras, sizes and an 4x4-cell mean colour of each training image, hashed.

    Robust to float noise in decoding (colours are rounded to 1/100), sensitive to another
    scene with the same view names (NeRF scenes all call their views r_0, r_1, ...)."""
    h = hashlib.sha256()
    for view, target in zip(train_views, targets):
        cam = view.camera
        h.update(str(view.name).encode())
        h.update(np.round(np.concatenate([cam.R.ravel(), cam.t, [cam.fx, cam.fy, cam.cx, cam.cy]]), 4).tobytes())
        img = np.asarray(target.detach().float().cpu().numpy() if hasattr(target, "detach") else target,
                         dtype=np.float64)
        hh, ww = img.shape[:2]
        h.update(f"{ww}x{hh}".encode())
        cells = [img[i * hh // 4:(i + 1) * hh // 4, j * ww // 4:(j + 1) * ww // 4].reshape(-1, img.shape[-1]).mean(0)
                 for i in range(4) for j in range(4) if hh >= 4 and ww >= 4]
        if cells:
            h.update(np.round(np.stack(cells), 2).tobytes())
    return {"views": len(train_views), "digest": h.hexdigest()}


def check_resume(path: Path, state: dict, fingerprint: dict, config: dict) -> None:
    """Refuse to continue checkpoint `path` on other training data or with other settings."""
    saved_fp = state.get("scene_fingerprint")
    if saved_fp is not None and saved_fp != fingerprint:
        raise GsgsError(f"{path}: this checkpoint was trained on other data (the training views' cameras or images "
                        "differ); resume with the same scene and resolution, or start afresh (`gsgs train ... "
                        "--overwrite`, or for a job folder delete its checkpoints/ folder)")
    saved = state.get("config") or {}
    diffs = [f"{k}: {_short(saved[k])} in the checkpoint, {_short(config[k])} now"
             for k in sorted(set(saved) & set(config)) if k not in RESUME_MAY_DIFFER and saved[k] != config[k]]
    if diffs:
        raise GsgsError(f"{path}: this checkpoint was trained with other settings ({'; '.join(diffs)}); resume with "
                        "the checkpoint's settings, or start afresh (`gsgs train ... --overwrite`, or for a job "
                        "folder delete its checkpoints/ folder)")


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."
