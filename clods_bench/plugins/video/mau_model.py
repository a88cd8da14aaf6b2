"""The MAU network (Chang et al. NeurIPS 2021, "MAU: A Motion-Aware Unit for Video Prediction and Beyond").

A recurrent predictor, one frame per step. Each frame is encoded (a 1x1 conv, then log2(sr_size) stride-2
3x3 convs, LeakyReLU) into the spatial state S; a stack of MAU cells updates (temporal state T, S); the
decoder (transposed convs) and a 1x1 readout give the next frame. A cell attends over its last `tau`
temporal states: weights = softmax over the window of <S_prev_i, conv(S_now)> / sqrt(C*h*w), the previous
spatial states S_prev_i scored against the current one; the attended state (the motion trend) is fused with
the current T through a sigmoid gate, and T and S exchange information through two more gates. Every cell
convolution is followed by a LayerNorm over (C,h,w) with an elementwise affine of that shape, as in the authors'
code (ZhengChang467/MAU, and OpenSTL's port), so a network is built for one latent size. PyTorch's default
initialisation, as theirs. The authors' network also holds two 1x1 convolutions its forward never calls (`merge`,
`conv_last_sr`); they are left out here.
"""

from __future__ import annotations

import math

import torch
from torch import nn


def _conv_norm(c_in: int, c_out: int, kernel: int, size: tuple[int, int]) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, kernel, padding=kernel // 2), nn.LayerNorm([c_out, *size]))


class MAUCell(nn.Module):
    """One motion-aware unit on (B,C,h,w) states of latent size `size` = (h, w) with a window of `tau` previous states."""

    def __init__(self, channels: int, kernel: int, tau: int, size: tuple[int, int]) -> None:
        super().__init__()
        self.channels, self.tau = channels, tau
        self.conv_t = _conv_norm(channels, 3 * channels, kernel, size)
        self.conv_t_next = _conv_norm(channels, channels, kernel, size)
        self.conv_s = _conv_norm(channels, 3 * channels, kernel, size)
        self.conv_s_next = _conv_norm(channels, channels, kernel, size)

    def attention(self, s_now: torch.Tensor, s_prev: torch.Tensor) -> torch.Tensor:
        """(tau,B) weights, summing to one over the window: softmax_i <s_prev[i], conv(s_now)> / sqrt(C*h*w)."""
        query = self.conv_s_next(s_now)
        scores = (s_prev * query.unsqueeze(0)).sum(dim=(2, 3, 4)) / math.sqrt(query[0].numel())
        return torch.softmax(scores, dim=0)

    def forward(self, t_now: torch.Tensor, s_now: torch.Tensor, t_prev: torch.Tensor, s_prev: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """New (T, S) from the current states and the windows t_prev, s_prev (tau,B,C,h,w)."""
        weights = self.attention(s_now, s_prev)
        trend = (t_prev * weights[:, :, None, None, None]).sum(dim=0)
        gate = torch.sigmoid(self.conv_t_next(t_now))
        fused = t_now * gate + (1 - gate) * trend
        t_g, t_t, t_s = torch.split(self.conv_t(fused), self.channels, dim=1)
        s_g, s_t, s_s = torch.split(self.conv_s(s_now), self.channels, dim=1)
        t_gate, s_gate = torch.sigmoid(t_g), torch.sigmoid(s_g)
        return t_gate * t_t + (1 - t_gate) * s_t, s_gate * s_s + (1 - s_gate) * t_s


class MAU(nn.Module):
    """(B,C,3,H,W) context of H x W = `image_size` -> (B,C-1+future,3,H,W): the predictions of frames 1..C-1+future,
    one step at a time."""

    def __init__(self, hidden: int, num_layers: int, kernel: int, tau: int, downsamples: int, image_size: tuple[int, int]) -> None:
        super().__init__()
        size = (image_size[0] >> downsamples, image_size[1] >> downsamples)
        self.hidden, self.tau = hidden, tau
        enc: list[nn.Module] = [nn.Sequential(nn.Conv2d(3, hidden, 1), nn.LeakyReLU(0.2))]
        enc += [nn.Sequential(nn.Conv2d(hidden, hidden, 3, stride=2, padding=1), nn.LeakyReLU(0.2)) for _ in range(downsamples)]
        self.enc = nn.Sequential(*enc)
        self.cells = nn.ModuleList(MAUCell(hidden, kernel, tau, size) for _ in range(num_layers))
        dec: list[nn.Module] = [
            nn.Sequential(nn.ConvTranspose2d(hidden, hidden, 3, stride=2, padding=1, output_padding=1), nn.LeakyReLU(0.2)) for _ in range(downsamples - 1)
        ]
        if downsamples:
            dec.append(nn.ConvTranspose2d(hidden, hidden, 3, stride=2, padding=1, output_padding=1))
        self.dec = nn.Sequential(*dec)
        self.readout = nn.Conv2d(hidden, 3, 1)

    def forward(self, context: torch.Tensor, future: int, truth: torch.Tensor | None = None, use_truth: torch.Tensor | None = None) -> torch.Tensor:
        """Frames 1..C-1+future; after the context each step gets the previous prediction, or (scheduled sampling)
        the true frame truth[:, k-1] where use_truth[:, k-1] (B,future-1) is true."""
        c = context.shape[1]
        t_states: list[torch.Tensor] = []
        t_hist: list[list[torch.Tensor]] = []
        s_hist: list[list[torch.Tensor]] = []
        outputs: list[torch.Tensor] = []
        for step in range(c - 1 + future):
            if step < c:
                frame = context[:, step]
            else:
                frame = outputs[-1]
                if truth is not None and use_truth is not None:
                    mask = use_truth[:, step - c].to(frame.dtype)[:, None, None, None]
                    frame = mask * truth[:, step - c] + (1 - mask) * frame
            s = self.enc(frame)
            if step == 0:  # zero temporal states and windows of zeros
                zeros = torch.zeros_like(s)
                t_states = [zeros] * len(self.cells)
                t_hist = [[zeros] * self.tau for _ in self.cells]
                s_hist = [[zeros] * self.tau for _ in self.cells]
            for i, cell in enumerate(self.cells):
                t_prev, s_prev = torch.stack(t_hist[i][-self.tau :]), torch.stack(s_hist[i][-self.tau :])
                s_hist[i].append(s)
                t_states[i], s = cell(t_states[i], s, t_prev, s_prev)
                t_hist[i].append(t_states[i])
            outputs.append(self.readout(self.dec(s)))
        return torch.stack(outputs, dim=1)
