"""Monocular depth sources behind one interface.

An estimator maps an RGB image (H, W, 3) float in [0, 1] to *relative inverse depth*
(H, W) (near = large), the convention of DPT-style models; the depth regulariser compares
it with the rendered inverse depth. Weights are read from a local folder only (the
transformers layout: config.json + weights + preprocessor_config.json), never from a hub.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from gsgs_engine import GsgsError


class DptDepthEstimator:
    """Any transformers depth-estimation model folder (DPT, DPT-hybrid, Depth Anything, ...)."""

    name = "dpt"

    def __init__(self, model_dir: str | os.PathLike, device: str = "cpu"):
        model_dir = Path(model_dir)
        if not (model_dir / "config.json").is_file():
            raise GsgsError(f"{model_dir}: not a depth-estimation model folder (no config.json); point the depth "
                            "estimator setting at a local transformers model folder, or use --depth none")
        os.environ.setdefault("HF_HUB_OFFLINE", "1")
        from transformers import AutoImageProcessor, AutoModelForDepthEstimation

        self.model_dir = model_dir
        self.device = torch.device(device)
        self.processor = AutoImageProcessor.from_pretrained(model_dir, local_files_only=True)
        # safetensors only: a pickled pytorch_model.bin from a received folder could run code when loaded
        self.model = AutoModelForDepthEstimation.from_pretrained(model_dir, local_files_only=True,
                                                                 use_safetensors=True).to(self.device).eval()

    @torch.no_grad()
    def __call__(self, image: torch.Tensor | np.ndarray) -> torch.Tensor:
        img = image.detach().cpu().numpy() if isinstance(image, torch.Tensor) else np.asarray(image)
        h, w = img.shape[:2]
        u8 = (np.clip(img[..., :3], 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
        inputs = self.processor(images=u8, return_tensors="pt").to(self.device)
        pred = self.model(**inputs).predicted_depth  # (1, h', w') relative inverse depth
        pred = F.interpolate(pred[:, None].float(), size=(h, w), mode="bicubic", align_corners=False)[0, 0]
        return pred.cpu()


def load_depth_estimator(spec: str | None, device: str = "cpu") -> DptDepthEstimator | None:
    """`None` / "none" -> no estimator; otherwise a local model folder."""
    if spec is None or str(spec).lower() in ("", "none"):
        return None
    return DptDepthEstimator(spec, device=device)


def save_tiny_dpt(folder: str | os.PathLike, seed: int = 0) -> Path:
    """A tiny randomly initialised DPT in the real transformers layout (tests, wiring checks).

    Its predictions are meaningless; it exercises exactly the loading and inference path a
    real DPT folder takes.
    """
    from transformers import DPTConfig, DPTForDepthEstimation, DPTImageProcessor

    torch.manual_seed(seed)
    cfg = DPTConfig(hidden_size=32, num_hidden_layers=4, num_attention_heads=2, intermediate_size=37, image_size=32,
                    patch_size=8, backbone_out_indices=[0, 1, 2, 3], neck_hidden_sizes=[8, 16, 32, 32],
                    fusion_hidden_size=16, head_in_index=-1)
    folder = Path(folder)
    DPTForDepthEstimation(cfg).save_pretrained(folder)
    DPTImageProcessor(size={"height": 32, "width": 32}).save_pretrained(folder)
    return folder
