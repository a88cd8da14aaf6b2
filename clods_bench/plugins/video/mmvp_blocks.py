"""The convolutional blocks MMVP (Zhong et al. ICCV 2023) builds its image paths from: ESRGAN's residual-in-residual
dense block (RRDB) for the encoder, decoder and enhancer, a residual block that downsamples the encoder, a
transposed-conv block that upsamples the decoder and concatenates a skip, and the conv-BatchNorm-LeakyReLU
layer of the motion paths. Slopes, biases and layer order are those of MMVP's authors' code."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

RDB_SLOPE = 0.2
"""LeakyReLU slope inside the dense blocks (ESRGAN)."""
RESIDUAL_SCALE = 0.2
"""Weight of a dense block's (and an RRDB's) residual branch (ESRGAN)."""


class DenseBlock(nn.Module):
    """Four 3x3 convs, each reading the input and every earlier output; x + 0.2 x the last one."""

    def __init__(self, channels: int, growth: int) -> None:
        super().__init__()
        self.convs = nn.ModuleList(nn.Conv2d(channels + i * growth, growth if i < 3 else channels, 3, padding=1) for i in range(4))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        feats = [x]
        for i, conv in enumerate(self.convs):
            y = conv(torch.cat(feats, dim=1))
            if i < 3:
                feats.append(F.leaky_relu(y, RDB_SLOPE))
        return x + RESIDUAL_SCALE * y


class RRDB(nn.Module):
    """Three dense blocks (growth = channels / 2) in a chain; x + 0.2 x their output."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.blocks = nn.Sequential(*(DenseBlock(channels, channels // 2) for _ in range(3)))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + RESIDUAL_SCALE * self.blocks(x)


class DownBlock(nn.Module):
    """Residual downsampling by 2 or 4: ReLU(conv3x3 stride 2), ReLU(conv3x3), plus a 1x1 stride-2 shortcut; a 2x2
    max-pool after the sum for a factor of 4; LeakyReLU(0.01) at the end."""

    def __init__(self, cin: int, cout: int, factor: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride=2, padding=1)
        self.conv2 = nn.Conv2d(cout, cout, 3, padding=1)
        self.shortcut = nn.Conv2d(cin, cout, 1, stride=2)
        self.pool = factor == 4

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # The 1x1 stride-2 shortcut as a 1x1 conv of every other pixel: the same function, but oneDNN 3.12's 1x1
        # stride-2 backward corrupts memory on AVX2 CPUs when the gradient arrives channels-last (a crash at ci).
        short = F.conv2d(x[:, :, ::2, ::2], self.shortcut.weight, self.shortcut.bias)
        y = F.relu(self.conv2(F.relu(self.conv1(x)))) + short
        if self.pool:
            y = F.max_pool2d(y, 2)
        return F.leaky_relu(y)


class UpBlock(nn.Module):
    """Transposed conv (kernel = stride = factor), then [skip, upsampled] concatenated when there is a skip, then
    ReLU(conv3x3 without bias)."""

    def __init__(self, cin: int, cout: int, factor: int, skip: bool) -> None:
        super().__init__()
        self.up = nn.ConvTranspose2d(cin, cout, factor, stride=factor)
        self.conv = nn.Conv2d(2 * cout if skip else cout, cout, 3, padding=1, bias=False)

    def forward(self, x: torch.Tensor, skip: torch.Tensor | None = None) -> torch.Tensor:
        x = self.up(x)
        if skip is not None:
            x = torch.cat([skip, x], dim=1)
        return F.relu(self.conv(x))


class ConvBNAct(nn.Module):
    """conv (stride `stride`) -> BatchNorm -> LeakyReLU(0.01): the layer of MMVP's motion paths (2D or 3D)."""

    def __init__(self, cin: int, cout: int, kernel: int = 3, stride: int = 1, dims: int = 2) -> None:
        super().__init__()
        conv, norm = (nn.Conv2d, nn.BatchNorm2d) if dims == 2 else (nn.Conv3d, nn.BatchNorm3d)
        self.conv = conv(cin, cout, kernel, stride=stride, padding=kernel // 2)
        self.norm = norm(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.leaky_relu(self.norm(self.conv(x)))
