"""SimVP v2's per-frame encoder and decoder layers (Tan et al., "SimVP: Towards Simple yet Powerful Spatiotemporal
Predictive Learning"; OpenSTL's `ConvSC`), the ones TAU's paper and code use.

A layer is a 3x3 convolution (stride 2 when downsampling; when upsampling a convolution to 4x the channels then a
PixelShuffle(2)), GroupNorm(2) and SiLU. Downsampling alternates no, yes, no, yes, ... over an even number of layers
(the decoder mirrors it), and the decoder's last layer sees the decoded features plus the first encoder layer's
output. Convolutions start from a truncated normal of std 0.02 with zero bias, as in OpenSTL.
"""

from __future__ import annotations

import torch
from torch import nn

from clods_bench.plugins.video.weight_init import trunc_normal_init


class ConvSC2(nn.Module):
    """3x3 convolution (stride 2 / conv + PixelShuffle when resampling), GroupNorm(2), SiLU; truncated-normal init."""

    def __init__(self, c_in: int, c_out: int, downsample: bool = False, upsample: bool = False) -> None:
        super().__init__()
        stride = 2 if downsample else 1
        padding = (3 - stride + 1) // 2  # OpenSTL's padding rule for a 3x3 kernel: 1 at either stride
        if upsample:
            self.conv: nn.Module = nn.Sequential(nn.Conv2d(c_in, 4 * c_out, 3, padding=padding), nn.PixelShuffle(2))
        else:
            self.conv = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=padding)
        self.norm = nn.GroupNorm(2, c_out)
        self.act = nn.SiLU()
        trunc_normal_init(self.conv, std=0.02)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.norm(self.conv(x)))


def samplings(num_layers: int) -> list[bool]:
    """Which encoder layers halve the resolution: False, True, False, True, ... (`num_layers` even)."""
    return [i % 2 == 1 for i in range(num_layers)]


def encoder(c_in: int, hid_s: int, num_layers: int) -> nn.ModuleList:
    """The per-frame encoder: `num_layers` ConvSC2 layers, every second one downsampling."""
    return nn.ModuleList(ConvSC2(c_in if i == 0 else hid_s, hid_s, downsample=s) for i, s in enumerate(samplings(num_layers)))


def decoder(hid_s: int, num_layers: int) -> nn.ModuleList:
    """The per-frame decoder: the encoder's layers mirrored, upsampling where it downsampled (the readout is separate)."""
    return nn.ModuleList(ConvSC2(hid_s, hid_s, upsample=s) for s in reversed(samplings(num_layers)))
