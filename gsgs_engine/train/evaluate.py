"""Evaluation on held-out views: PSNR, SSIM, LPIPS (null with a reason when unavailable), renders."""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

MAX_RENDERS_WHEN_MANY = 8
ALL_RENDERS_UP_TO = 30


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "view"


def write_png(path: Path, rgb: np.ndarray) -> None:
    import cv2

    img = (np.clip(rgb, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(img, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")


def _lpips(img: torch.Tensor, gt: torch.Tensor) -> tuple[float | None, str]:
    from gsgs_engine.metrics import lpips_or_none

    value, reason = lpips_or_none(img, gt)
    return (None if value is None else float(value)), (reason or "")


def evaluate_views(render_fn: Callable, views: list, renders_dir: Path | None = None,
                   max_renders: int | None = None) -> dict:
    """Render every view with `render_fn(camera) -> RenderOutput` and compare with its image.

    Renders are written for all views when there are at most 30, else for the first 8
    (or `max_renders`). Returns mean psnr / ssim / lpips and a per-view list.
    """
    from gsgs_engine.metrics import psnr, ssim

    if max_renders is None:
        max_renders = len(views) if len(views) <= ALL_RENDERS_UP_TO else MAX_RENDERS_WHEN_MANY
    t0 = time.perf_counter()
    per_view = []
    lpips_values: list[float] = []
    lpips_reason = ""
    for i, view in enumerate(views):
        gt = torch.from_numpy(np.ascontiguousarray(view.image(), dtype=np.float32))
        with torch.no_grad():
            img = render_fn(view.camera).color.detach().clamp(0.0, 1.0).cpu()  # the model may live on a GPU
            entry = {"name": view.name, "psnr": float(psnr(img, gt)), "ssim": float(ssim(img, gt))}
            lp, reason = _lpips(img, gt)
        if lp is None:
            lpips_reason = reason
        else:
            lpips_values.append(lp)
        entry["lpips"] = lp
        per_view.append(entry)
        if renders_dir is not None and i < max_renders:
            write_png(Path(renders_dir) / f"{i:03d}_{_safe_name(view.name)}.png", img.numpy())
    result = {
        "psnr": float(np.mean([v["psnr"] for v in per_view])) if per_view else None,
        "ssim": float(np.mean([v["ssim"] for v in per_view])) if per_view else None,
        "lpips": float(np.mean(lpips_values)) if per_view and len(lpips_values) == len(per_view) else None,
        "num_views": len(per_view),
        "per_view": per_view,
        "seconds": time.perf_counter() - t0,
    }
    if result["lpips"] is None:
        result["lpips_reason"] = lpips_reason or ("no test views" if not per_view else "LPIPS unavailable")
    return result
