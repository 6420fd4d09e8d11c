"""Evaluation on held-out views: PSNR, SSIM, LPIPS VGG and AlexNet (null with a reason when the weights
are absent), renders."""

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


# "lpips" is the VGG value (what the 3DGS-family sparse-view papers report); AlexNet is recorded beside it
LPIPS_MAIN_NET = "vgg"
LPIPS_NETS = ("vgg", "alex")


def lpips_fields(evaluation: dict) -> dict:
    """The LPIPS keys metrics.json carries: lpips (= lpips_vgg), lpips_net, lpips_vgg, lpips_alex, and
    lpips_reason only when the value is null."""
    fields = {"lpips": evaluation.get("lpips"), "lpips_net": LPIPS_MAIN_NET}
    fields.update({f"lpips_{net}": evaluation.get(f"lpips_{net}") for net in LPIPS_NETS})
    if fields["lpips"] is None:
        fields["lpips_reason"] = evaluation.get("lpips_reason") or "LPIPS unavailable"
    return fields


def mean_present(values: list) -> float | None:
    present = [v for v in values if v is not None]
    return float(np.mean(present)) if present else None


def evaluate_views(render_fn: Callable, views: list, renders_dir: Path | None = None,
                   max_renders: int | None = None, region_fn: Callable | None = None,
                   lpips: bool = True) -> dict:
    """Render every view with `render_fn(camera) -> RenderOutput` and compare with its image.

    Renders are written for all views when there are at most 30, else for the first 8
    (or `max_renders`). Returns mean psnr / ssim / lpips and a per-view list.
    region_fn(view) -> bool H x W mask or None: PSNR inside that region too ("psnr_region", the mean
    over the views whose region has pixels; gsgs bench dynamic scores the moving people with it) and outside it
    ("psnr_outside": the rest of the view, a video's still room).
    lpips=False skips LPIPS (its value is then None, with the reason).
    """
    from gsgs_engine.metrics import lpips_or_none, masked_psnr, psnr, ssim

    if max_renders is None:
        max_renders = len(views) if len(views) <= ALL_RENDERS_UP_TO else MAX_RENDERS_WHEN_MANY
    t0 = time.perf_counter()
    per_view = []
    lpips_values: dict[str, list[float]] = {net: [] for net in LPIPS_NETS}
    lpips_reason = ""
    for i, view in enumerate(views):
        gt = torch.from_numpy(np.ascontiguousarray(view.image(), dtype=np.float32))
        with torch.no_grad():
            img = render_fn(view.camera).color.detach().clamp(0.0, 1.0).cpu()  # the model may live on a GPU
            entry = {"name": view.name, "psnr": float(psnr(img, gt)), "ssim": float(ssim(img, gt))}
            if region_fn is not None:
                region = region_fn(view)
                entry["psnr_region"] = None if region is None else masked_psnr(img, gt, region)
                entry["psnr_outside"] = None if region is None else masked_psnr(img, gt, ~np.asarray(region))
            for net in LPIPS_NETS:
                lp, reason = lpips_or_none(img, gt, net=net) if lpips else (None, "LPIPS not asked for")
                entry[f"lpips_{net}"] = lp
                if lp is None:
                    lpips_reason = lpips_reason or reason
                else:
                    lpips_values[net].append(lp)
        entry["lpips"] = entry[f"lpips_{LPIPS_MAIN_NET}"]
        per_view.append(entry)
        if renders_dir is not None and i < max_renders:
            write_png(Path(renders_dir) / f"{i:03d}_{_safe_name(view.name)}.png", img.numpy())
    result = {
        "psnr": float(np.mean([v["psnr"] for v in per_view])) if per_view else None,
        "ssim": float(np.mean([v["ssim"] for v in per_view])) if per_view else None,
        **{f"lpips_{net}": float(np.mean(values)) if per_view and len(values) == len(per_view) else None
           for net, values in lpips_values.items()},
        "num_views": len(per_view),
        "per_view": per_view,
        **({key: mean_present([v.get(key) for v in per_view]) for key in ("psnr_region", "psnr_outside")}
           if region_fn is not None else {}),
        "seconds": time.perf_counter() - t0,
    }
    result["lpips"] = result[f"lpips_{LPIPS_MAIN_NET}"]
    result["lpips_net"] = LPIPS_MAIN_NET
    if result["lpips"] is None:
        result["lpips_reason"] = lpips_reason or ("no test views" if not per_view else "LPIPS unavailable")
    return result
