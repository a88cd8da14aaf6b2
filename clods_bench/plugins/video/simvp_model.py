"""The SimVP v1 network (Gao et al. CVPR 2022, "SimVP: Simpler yet Better Video Prediction"), as in its authors'
code (A4Bio/SimVP): a per-frame CNN encoder, a translator of Inception blocks over the time-stacked latents, a
per-frame CNN decoder.

Encoder: ConvSC layers (3x3 conv, GroupNorm(2), LeakyReLU(0.2)) with strides 1,2,1,2,...; the translator sees
(B, T*hid_s, h, w) and is a U-Net of Inception blocks (1x1 conv to hid_t/2, then the sum of grouped convolutions of
several kernel sizes, each with GroupNorm and LeakyReLU); the decoder mirrors the encoder with transposed
convolutions and feeds its last layer the decoded features concatenated with the first encoder layer's output;
a 1x1 readout. T_out = T_in frames are predicted at once. PyTorch's default initialisation, as the authors' code.
"""

from __future__ import annotations

import abc

import torch
from torch import nn


class ConvSC(nn.Module):
    """3x3 convolution (transposed when upsampling by 2) + GroupNorm(2) + LeakyReLU(0.2)."""

    def __init__(self, c_in: int, c_out: int, stride: int, transpose: bool = False) -> None:
        super().__init__()
        if transpose and stride == 2:
            self.conv: nn.Module = nn.ConvTranspose2d(c_in, c_out, 3, stride=2, padding=1, output_padding=1)
        else:
            self.conv = nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1)
        self.norm = nn.GroupNorm(2, c_out)
        self.act = nn.LeakyReLU(0.2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.norm(self.conv(x)))


def strides(num_layers: int) -> list[int]:
    """SimVP's encoder strides: 1, 2, 1, 2, ... (one halving per pair of layers)."""
    return [2 if i % 2 == 1 else 1 for i in range(num_layers)]


def inception_groups(c_hid: int, groups: int) -> int:
    """Groups of an Inception branch: `groups`, or 1 when the branch input width is not divisible by it (SimVP's rule)."""
    return groups if c_hid % groups == 0 else 1


class GroupConvNormAct(nn.Module):
    """One Inception branch: grouped k x k convolution, GroupNorm with as many groups, LeakyReLU(0.2)."""

    def __init__(self, c_in: int, c_out: int, kernel: int, groups: int) -> None:
        super().__init__()
        g = inception_groups(c_in, groups)
        self.conv = nn.Conv2d(c_in, c_out, kernel, padding=kernel // 2, groups=g)
        self.norm = nn.GroupNorm(g, c_out)
        self.act = nn.LeakyReLU(0.2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.act(self.norm(self.conv(x)))


class Inception(nn.Module):
    """1x1 convolution to `c_hid`, then the sum of the branches with the given kernel sizes."""

    def __init__(self, c_in: int, c_hid: int, c_out: int, kernels: tuple[int, ...], groups: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_hid, 1)
        self.branches = nn.ModuleList(GroupConvNormAct(c_hid, c_out, k, groups) for k in kernels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        h = self.conv1(x)
        return sum(b(h) for b in self.branches)  # type: ignore[return-value]


class Translator(nn.Module):
    """SimVP v1's U-Net of `num_layers` (>= 2) Inception blocks over (B, T*C, h, w): the encoder's last output enters
    the first decoder block alone; each later decoder block sees its input concatenated with the mirrored encoder output."""

    def __init__(self, channels: int, hidden: int, num_layers: int, kernels: tuple[int, ...], groups: int) -> None:
        super().__init__()
        half = hidden // 2
        self.enc = nn.ModuleList([Inception(channels, half, hidden, kernels, groups)])
        self.enc.extend(Inception(hidden, half, hidden, kernels, groups) for _ in range(num_layers - 1))
        self.dec = nn.ModuleList([Inception(hidden, half, hidden, kernels, groups)])
        self.dec.extend(Inception(2 * hidden, half, hidden, kernels, groups) for _ in range(num_layers - 2))
        self.dec.append(Inception(2 * hidden, half, channels, kernels, groups))

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        skips = []
        for layer in self.enc:
            z = layer(z)
            skips.append(z)
        z = self.dec[0](z)
        for layer, skip in zip(self.dec[1:], reversed(skips[:-1])):
            z = layer(torch.cat([z, skip], dim=1))
        return z


class EncoderTranslatorDecoder(nn.Module, abc.ABC):
    """SimVP's frame of work, shared with TAU (SimVP v2): a per-frame conv encoder (`enc`), a translator over the frames
    stacked on channels (`translator`), a per-frame conv decoder (`dec`) whose last layer also sees the first encoder
    layer's output (`merge_skip`), and a 1x1 `readout` to RGB. (B,T,3,H,W) -> (B,T,3,H,W)."""

    enc: nn.ModuleList
    translator: nn.Module
    dec: nn.ModuleList
    readout: nn.Module

    @abc.abstractmethod
    def merge_skip(self, z: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        """How the last decoder layer's input combines the decoded features with the skip connection."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, t, c, h, w = x.shape
        z = x.reshape(b * t, c, h, w)
        skip = z
        for i, layer in enumerate(self.enc):
            z = layer(z)
            if i == 0:
                skip = z
        _, cz, hz, wz = z.shape
        z = self.translator(z.reshape(b, t * cz, hz, wz)).reshape(b * t, cz, hz, wz)
        for layer in self.dec[:-1]:
            z = layer(z)
        z = self.dec[-1](self.merge_skip(z, skip))
        return self.readout(z).reshape(b, t, c, h, w)


class SimVP(EncoderTranslatorDecoder):
    """SimVP v1: (B,T,3,H,W) frames in [0,1] -> (B,T,3,H,W), the next T frames."""

    def __init__(self, frames: int, hid_s: int, hid_t: int, enc_layers: int, trans_layers: int, kernels: tuple[int, ...], groups: int) -> None:
        super().__init__()
        self.frames = frames
        st = strides(enc_layers)
        self.enc = nn.ModuleList(ConvSC(3 if i == 0 else hid_s, hid_s, s) for i, s in enumerate(st))
        self.translator = Translator(frames * hid_s, hid_t, trans_layers, kernels, groups)
        rev = list(reversed(st))
        self.dec = nn.ModuleList(ConvSC(hid_s, hid_s, s, transpose=True) for s in rev[:-1])
        self.dec.append(ConvSC(2 * hid_s, hid_s, rev[-1], transpose=True))
        self.readout = nn.Conv2d(hid_s, 3, 1)

    def merge_skip(self, z: torch.Tensor, skip: torch.Tensor) -> torch.Tensor:
        """SimVP v1 feeds the last decoder layer the decoded features concatenated with the first encoder layer's."""
        return torch.cat([z, skip], dim=1)
