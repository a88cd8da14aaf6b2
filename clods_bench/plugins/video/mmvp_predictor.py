"""MMVP's matrix predictor: a small U-Net with 3D (time x space) convolutions that reads the P-1 observed motion
matrices and writes the logits of the F matrices from the last observed frame to each future frame (the authors'
`PredictModel` with its direct predictor, which MMVP uses for Moving MNIST and KTH and OpenSTL always).

Each source position's row of a matrix is an image over the target grid (h x w). Per row and time step: embed
(1 -> n channels), two conv-BN-LeakyReLU layers, one stride-2; a 3D conv over (time, space); a 1x1 conv maps the
P-1 time steps' channels to F (then LeakyReLU, then BatchNorm); a second stride-2 level with a 3D conv over the F
future steps; nearest upsampling with the first level's features concatenated, a conv, nearest upsampling to
h x w, a conv, and a 3x3 readout to one channel."""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from clods_bench.plugins.video.mmvp_blocks import ConvBNAct


class MatrixPredictor(nn.Module):
    """(B,P-1,hw,hw) observed matrices (cosine similarities) -> (B,F,hw,hw) logits of the future ones."""

    def __init__(self, past: int, future: int, channels: int) -> None:
        super().__init__()
        n = channels
        self.past, self.future = past, future
        self.embed = nn.Conv2d(1, n, 3, padding=1, bias=False)
        self.pre = nn.Sequential(ConvBNAct(n, n), ConvBNAct(n, n))
        self.down1 = ConvBNAct(n, n, stride=2)
        self.time1 = ConvBNAct(n, n, dims=3)
        self.translate = nn.Conv2d(n * past, n * future, 1)
        self.translate_norm = nn.BatchNorm2d(n * future)
        self.down2 = ConvBNAct(n, 2 * n, stride=2)
        self.time2 = ConvBNAct(2 * n, 2 * n, dims=3)
        self.up1 = ConvBNAct(3 * n, n)
        self.up2 = ConvBNAct(n, n)
        self.readout = nn.Conv2d(n, 1, 3, padding=1, bias=False)

    def forward(self, matrices: torch.Tensor, grid: tuple[int, int]) -> torch.Tensor:
        """`grid`: the (h, w) of the positions, h * w = hw."""
        b, k, hw, _ = matrices.shape
        h, w = grid
        rows = b * hw  # one sequence per batch element and source position
        x = self.embed(matrices.reshape(b * k * hw, 1, h, w))
        x = x.reshape(b, k, hw, -1, h, w).transpose(1, 2).reshape(rows * k, -1, h, w)
        x = self.down1(self.pre(x))
        n, h1, w1 = x.shape[1:]
        x = self.time1(x.reshape(rows, k, n, h1, w1).transpose(1, 2)).transpose(1, 2)  # (rows, k, n, h1, w1)
        x1 = self.translate_norm(F.leaky_relu(self.translate(x.reshape(rows, k * n, h1, w1))))
        x1 = x1.reshape(rows * self.future, n, h1, w1)
        x2 = self.down2(x1)
        x2 = x2.reshape(rows, self.future, 2 * n, *x2.shape[2:]).transpose(1, 2)
        x2 = self.time2(x2).transpose(1, 2).reshape(rows * self.future, 2 * n, *x2.shape[3:])
        x3 = self.up1(torch.cat([F.interpolate(x2, size=(h1, w1)), x1], dim=1))
        out = self.readout(self.up2(F.interpolate(x3, size=(h, w))))  # (rows*F, 1, h, w)
        return out.reshape(b, hw, self.future, hw).transpose(1, 2)
