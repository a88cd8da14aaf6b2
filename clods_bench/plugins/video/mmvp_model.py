"""The MMVP network (Zhong et al. ICCV 2023, "MMVP: Motion-Matrix-based Video Prediction"): appearance and
motion kept apart.

A per-frame CNN encoder (SimVP's ConvSC stack) gives appearance features (B,c,h,w); a small conv head projects
them to motion features, and the motion matrix of two consecutive frames is the (hw x hw) matrix of cosine
similarities between the motion features of frame t (rows, source positions) and of frame t+1 (columns,
target positions). A matrix predictor reads each source row of the C-1 past matrices as a C-1 channel h x w
image over target positions and outputs C rows: the logits of the matrices from the last observed frame to
each of the C future frames. A future feature map is their composition with the last frame's appearance
features: every target position takes the softmax-over-sources weighted mean of the source features. The
decoder (transposed ConvSC stack, 1x1 readout) renders it, and an enhancer refines the result together with
the last image composed by the same matrix (MMVP's `res_cat_img`: the image pixel-unshuffled to the matrix
resolution, composed, shuffled back).
"""

from __future__ import annotations

import torch
from torch import nn

from clods_bench.plugins.video.simvp_model import ConvSC, strides


def motion_matrix(prev: torch.Tensor, nxt: torch.Tensor) -> torch.Tensor:
    """(B,hw,hw) cosine similarities between the features (B,c,h,w) at each position of `prev` (rows) and of `nxt` (columns)."""
    a = torch.nn.functional.normalize(prev.flatten(2), dim=1, eps=1e-6)
    b = torch.nn.functional.normalize(nxt.flatten(2), dim=1, eps=1e-6)
    return a.transpose(1, 2) @ b


def compose(logits: torch.Tensor, feats: torch.Tensor, temperature: float = 1.0) -> torch.Tensor:
    """(B,c,h,w) future features: at each target position (column of `logits`, (B,hw,hw)) the mean of the source
    features (B,c,h,w) weighted by the softmax over sources (rows) of logits/temperature."""
    b, c, h, w = feats.shape
    weights = torch.softmax(logits / temperature, dim=1)  # (B, source, target)
    return (feats.flatten(2) @ weights).reshape(b, c, h, w)


class MatrixPredictor(nn.Module):
    """(B,K,hw,hw) past motion matrices -> (B,F,hw,hw) logits of the F future ones, a conv net over each source row's h x w map."""

    def __init__(self, past: int, future: int, hidden: int) -> None:
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv2d(past, hidden, 3, padding=1),
            nn.LeakyReLU(0.2),
            nn.Conv2d(hidden, hidden, 3, padding=1),
            nn.LeakyReLU(0.2),
            nn.Conv2d(hidden, future, 3, padding=1),
        )

    def forward(self, matrices: torch.Tensor, h: int, w: int) -> torch.Tensor:
        b, k, hw, _ = matrices.shape
        rows = matrices.permute(0, 2, 1, 3).reshape(b * hw, k, h, w)
        out = self.net(rows)
        return out.reshape(b, hw, -1, hw).permute(0, 2, 1, 3)


class MMVP(nn.Module):
    """(B,C,3,H,W) frames in [0,1] -> (B,C,3,H,W): the next C frames."""

    def __init__(self, frames: int, hid_s: int, motion_channels: int, predictor_hidden: int, enc_layers: int) -> None:
        super().__init__()
        st = strides(enc_layers)
        self.factor = 2 ** sum(s == 2 for s in st)
        self.enc = nn.Sequential(*(ConvSC(3 if i == 0 else hid_s, hid_s, s) for i, s in enumerate(st)))
        self.motion = nn.Sequential(
            ConvSC(hid_s, motion_channels, 1), ConvSC(motion_channels, motion_channels, 1), nn.Conv2d(motion_channels, motion_channels, 3, padding=1)
        )
        self.predictor = MatrixPredictor(frames - 1, frames, predictor_hidden)
        self.dec = nn.Sequential(*(ConvSC(hid_s, hid_s, s, transpose=True) for s in reversed(st)), nn.Conv2d(hid_s, 3, 1))
        self.enhancer = nn.Sequential(nn.Conv2d(6, hid_s, 3, padding=1), nn.LeakyReLU(0.2), nn.Conv2d(hid_s, 3, 3, padding=1))

    def matrices(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Appearance features of the last frame (B,c,h,w) and the C-1 past motion matrices (B,C-1,hw,hw)."""
        b, t, c, hh, ww = x.shape
        feats = self.enc(x.reshape(b * t, c, hh, ww))
        _, cf, h, w = feats.shape
        motion = self.motion(feats).reshape(b, t, -1, h, w)
        past = torch.stack([motion_matrix(motion[:, k], motion[:, k + 1]) for k in range(t - 1)], dim=1)
        return feats.reshape(b, t, cf, h, w)[:, -1], past

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, t, c, hh, ww = x.shape
        last, past = self.matrices(x)
        h, w = last.shape[-2:]
        logits = self.predictor(past, h, w)  # (B,F,hw,hw)
        f = logits.shape[1]
        flat = logits.reshape(b * f, h * w, h * w)
        feats = compose(flat, last.repeat_interleave(f, dim=0))
        pixels = torch.nn.functional.pixel_unshuffle(x[:, -1], self.factor).repeat_interleave(f, dim=0)
        moved = torch.nn.functional.pixel_shuffle(compose(flat, pixels), self.factor)
        decoded = self.dec(feats)
        out = decoded + self.enhancer(torch.cat([decoded, moved], dim=1))
        return out.reshape(b, f, c, hh, ww)
