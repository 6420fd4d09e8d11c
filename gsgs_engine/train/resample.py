"""Images and maps at a reduced resolution for the renders made smaller (issue 29).

A render at scale s of its camera (`Camera.scaled`) is compared with its target averaged over the
same pixel footprints: area averaging (box filter), the exact mean of each output pixel's source
pixels when the size divides evenly.
"""

from __future__ import annotations

import torch


def resize_area(image: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """An (H, W) or (H, W, C) tensor resized to (height, width) by area averaging (itself at the same size)."""
    if tuple(image.shape[:2]) == (height, width):
        return image
    x = image[None, None] if image.ndim == 2 else image.permute(2, 0, 1)[None]
    out = torch.nn.functional.interpolate(x.float(), size=(height, width), mode="area").to(image.dtype)
    return out[0, 0] if image.ndim == 2 else out[0].permute(1, 2, 0).contiguous()
