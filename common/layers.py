"""The layers every network of the system is built from (common/networks.py, common/critics.py,
common/bcq_networks.py): the simulator's shapes, a plain MLP, and PilotNet's conv trunk
(Bojarski et al. 2016: 24, 36, 48 5x5 stride 2; 64, 64 3x3) on the two stacked uint8 grayscale
frames, scaled to [0, 1]. A module of its own so the critics and BCQ's networks need not import
the factories that import them."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

IMAGE_SHAPE = (2, 64, 128)  # (frames t and t-1, height, width), the simulator contract
ACTION_DIM = 2  # steering, target speed
LOW_DIM = 3  # speed (1) + last action (2), joined after the conv trunk
PILOTNET_LAYERS = ((5, 2), (5, 2), (5, 2), (3, 1), (3, 1))  # (kernel, stride)


def mlp(in_dim: int, hidden: Sequence[int], out_dim: int, norm: bool = False) -> nn.Sequential:
    """ReLU hidden layers, linear output; with `norm` a LayerNorm before each ReLU."""
    layers: list[nn.Module] = []
    for width in hidden:
        layers += [nn.Linear(in_dim, width), *([nn.LayerNorm(width)] if norm else []), nn.ReLU()]
        in_dim = width
    layers.append(nn.Linear(in_dim, out_dim))
    return nn.Sequential(*layers)


class PilotNetTrunk(nn.Module):
    """Conv trunk on uint8 frames (B, 2, 64, 128) -> flat features (B, out_dim)."""

    def __init__(self, channels: Sequence[int], image_shape: Sequence[int] = IMAGE_SHAPE):
        super().__init__()
        layers: list[nn.Module] = []
        in_channels = image_shape[0]
        for out_channels, (kernel, stride) in zip(channels, PILOTNET_LAYERS, strict=True):
            layers += [nn.Conv2d(in_channels, out_channels, kernel, stride), nn.ReLU(inplace=True)]
            in_channels = out_channels
        # channels_last: oneDNN's (and cuDNN's) preferred layout, ~1.5x faster here on CPU;
        # Flatten still reads (C, H, W) in logical order, so features do not change
        self.layers = nn.Sequential(*layers, nn.Flatten()).to(memory_format=torch.channels_last)
        with torch.no_grad():
            self.out_dim = self.layers(torch.zeros(1, *image_shape)).shape[1]

    def forward(self, image: Tensor) -> Tensor:
        x = image.contiguous(memory_format=torch.channels_last).float().div_(255.0)
        return self.layers(x)
