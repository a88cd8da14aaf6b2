"""The MMVP network (Zhong et al. ICCV 2023, "MMVP: Motion-Matrix-based Video Prediction"), as the authors' code
builds it with `--filter_block --res_cat_img --scale_in_use 3 --use_direct_predictor` (OpenSTL's MMVP likewise).

Per frame: pixel-unshuffle by 2, a conv and RRDBs, then three residual downsampling levels (factors `downsample`,
channels 2n, 4n, 8n). Two filter blocks (three conv-BN-LeakyReLU each) turn the last two levels into motion
features (n and 2n channels) whose consecutive-frame cosine similarities are the motion matrices at two scales
(8x8 and 4x4 positions for a 64 px frame with the default factors). The matrix predictor reads the fine scale's
observed matrices and predicts the F future ones; the coarse scale's future matrices are the fine logits resized.
Every matrix is softmaxed over all its entries, and each future frame's features at the three used levels are
composed from all P observed frames through the chained matrices (the first level pixel-unshuffled to the fine
grid and back). A U-Net decoder (transposed convs with skips, RRDBs, 1x1 readout, pixel shuffle) renders them;
the observed images composed the same way (unshuffled to the fine grid) join the rendered frame in the enhancer
(a conv, RRDBs and a 1x1 readout at half the width), whose output is the prediction.

Extra frames after the first P (the training targets, which MMVP's training passes in too) are encoded and
filtered but not composed: they reach the output only through the filter blocks' BatchNorm batch statistics.
Frames are shifted by -`pixel_offset` on the way in and back on the way out (MMVP trains on [-0.5, 0.5]).
"""

from __future__ import annotations

import math

import torch
from torch import nn
from torch.nn import functional as F

from clods_bench.plugins.video.mmvp_blocks import RRDB, ConvBNAct, DownBlock, UpBlock
from clods_bench.plugins.video.mmvp_matrices import compose_chained, global_softmax, resize_matrices, similarity_matrices
from clods_bench.plugins.video.mmvp_predictor import MatrixPredictor


def total_factor(downsample: tuple[int, ...]) -> int:
    """Image sides must be divisible by this: 2 (the pixel unshuffle) times every level's factor."""
    return 2 * math.prod(downsample)


class MMVP(nn.Module):
    """(B,T>=P,C,H,W) frames -> (B,P,C,H,W): the P frames after the first P (P = `frames`; H and W divisible by
    `total_factor(downsample)`)."""

    def __init__(
        self, frames: int, channels: int = 16, predictor_channels: int = 8, downsample: tuple[int, int, int] = (2, 2, 2),
        encoder_blocks: int = 2, decoder_blocks: int = 2, enhancer_blocks: int = 2, image_channels: int = 3, pixel_offset: float = 0.5,
    ) -> None:  # fmt: skip
        super().__init__()
        n, f, c4 = channels, downsample, 4 * image_channels
        self.frames, self.downsample, self.pixel_offset = frames, tuple(downsample), pixel_offset
        self.stem = nn.Sequential(nn.Conv2d(c4, n, 3, padding=1), *(RRDB(n) for _ in range(encoder_blocks)))
        self.down = nn.ModuleList(DownBlock(n << i, n << (i + 1), f[i]) for i in range(3))
        self.filter_fine = nn.Sequential(ConvBNAct(4 * n, n), ConvBNAct(n, n), ConvBNAct(n, n))
        self.filter_coarse = nn.Sequential(ConvBNAct(8 * n, 2 * n), ConvBNAct(2 * n, 2 * n), ConvBNAct(2 * n, 2 * n))
        self.predictor = MatrixPredictor(frames - 1, frames, predictor_channels)
        self.up = nn.ModuleList([UpBlock(8 * n, 4 * n, f[2], True), UpBlock(4 * n, 2 * n, f[1], True), UpBlock(2 * n, n, f[0], False)])
        self.dec = nn.Sequential(*(RRDB(n) for _ in range(decoder_blocks)), nn.Conv2d(n, c4, 1))
        e = n // 2
        self.enhancer = nn.Sequential(nn.Conv2d(2 * image_channels, e, 3, padding=1), *(RRDB(e) for _ in range(enhancer_blocks)), nn.Conv2d(e, image_channels, 1))

    def future_matrices(self, fine: torch.Tensor, coarse: torch.Tensor) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
        """Softmaxed (observed, predicted) matrices at the fine and coarse scales from the motion features (B,T,c,h,w)."""
        p = self.frames
        sims = [similarity_matrices(m[:, :p]) for m in (fine, coarse)]
        grids = (fine.shape[-2], fine.shape[-1]), (coarse.shape[-2], coarse.shape[-1])
        logits = self.predictor(sims[0], grids[0])
        pred = [logits, resize_matrices(logits, *grids)]
        return [global_softmax(s) for s in sims], [global_softmax(m) for m in pred]

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        b, t, c, hh, ww = x.shape
        p, f = self.frames, self.downsample
        img = F.pixel_unshuffle((x - self.pixel_offset).reshape(b * t, c, hh, ww), 2)
        level0 = self.down[0](self.stem(img))
        level1 = self.down[1](level0)
        level2 = self.down[2](level1)
        fine, coarse = self.filter_fine(level1), self.filter_coarse(level2)
        past, pred = self.future_matrices(fine.reshape(b, t, *fine.shape[1:]), coarse.reshape(b, t, *coarse.shape[1:]))

        def composed(feats: torch.Tensor, scale: int, unshuffle: int = 1) -> torch.Tensor:
            """(B*P,...) future features of one level: unshuffled to the scale's grid, composed, shuffled back."""
            v = F.pixel_unshuffle(feats, unshuffle) if unshuffle > 1 else feats
            v = v.reshape(b, t, *v.shape[1:])[:, :p]
            out = compose_chained(v, past[scale], pred[scale]).flatten(0, 1)
            return F.pixel_shuffle(out, unshuffle) if unshuffle > 1 else out

        y = self.up[0](composed(level2, 1), composed(level1, 0))
        y = self.up[1](y, composed(level0, 0, f[1]))
        y = F.pixel_shuffle(self.dec(self.up[2](y)), 2)
        moved = F.pixel_shuffle(composed(img, 0, f[0] * f[1]), 2)
        out = self.enhancer(torch.cat([y, moved], dim=1))
        return out.reshape(b, p, c, hh, ww) + self.pixel_offset
