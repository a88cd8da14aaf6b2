"""TAU video predictor: the TAU network and the loss MSE + alpha * differential divergence, trained like SimVP (the
shared loop in `trainer.py`, checkpoint `tau.pt`).

Kept from the authors' recipe (OpenSTL's configs/mmnist/TAU.py, the TAU paper's Moving MNIST run: 64x64 frames,
10 -> 10, a moving object on a plain background, the closest of its configs to these cloth videos): SimVP v2's
encoder and decoder, TAU blocks with the 21 px attention and MLP ratio 8, OpenSTL's initialisation, alpha 0.1 and
the regulariser's temperature 0.1, stochastic depth from drop_path 0 (OpenSTL's rates 0.01 .. 0 over the blocks),
Adam without weight decay and a one-cycle schedule peaking at 1e-3. The presets shrink widths (hid_s, hid_t), block
counts, frames per window, batch and steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from clods_bench.errors import ClodsError
from clods_bench.plugins.video.tau_blocks import lka_kernels
from clods_bench.plugins.video.tau_model import TAU, differential_divergence
from clods_bench.plugins.video.trainer import WindowPredictor, WindowTrainConfig

WHERE = "video_config.tau"


@dataclass(frozen=True)
class TauConfig(WindowTrainConfig):
    """Options of the TAU predictor (`video_config.tau.*`); defaults are OpenSTL's Moving MNIST TAU config."""

    hid_s: int = 64
    """Channels of the per-frame encoder/decoder (OpenSTL TAU: hid_S 64)."""
    hid_t: int = 512
    """Channels of the translator's inner blocks (OpenSTL TAU: hid_T 512)."""
    enc_layers: int = 4
    """Encoder (and decoder) layers, even: every second one halves the resolution (OpenSTL TAU: N_S 4)."""
    trans_layers: int = 8
    """TAU blocks of the translator, >= 2 (OpenSTL TAU: N_T 8)."""
    kernel_size: int = 21
    """Receptive field of the statical attention, decomposed into a 5x5 depthwise and a dilation-3 depthwise conv (TAU: 21)."""
    mlp_ratio: float = 8.0
    """Hidden width of each block's MLP over its input width (OpenSTL TAU: 8)."""
    drop_path: float = 0.0
    """Stochastic depth of the last block; the others drop with rates from 0.01 towards it (OpenSTL Moving MNIST TAU: 0)."""
    alpha: float = 0.1
    """Weight of the differential divergence regularisation (TAU: 0.1 in every OpenSTL config)."""
    temperature: float = 0.1
    """Softmax temperature of the regularisation (OpenSTL's `diff_div_reg`: tau 0.1)."""

    def validate(self) -> None:
        """Raise ClodsError naming the field when an option cannot work."""
        self.validate_training("tau", ("hid_s", "hid_t", "enc_layers", "kernel_size"))
        if self.hid_s % 2:
            raise ClodsError(f"must be even (GroupNorm with 2 groups), got {self.hid_s}", where=f"{WHERE}.hid_s")
        if self.enc_layers % 2:
            raise ClodsError(f"must be even (layers alternate keep / halve, as SimVP v2's), got {self.enc_layers}", where=f"{WHERE}.enc_layers")
        if self.trans_layers < 2:
            raise ClodsError(f"must be >= 2 (first and last blocks change the width), got {self.trans_layers}", where=f"{WHERE}.trans_layers")
        if min(self.hid_t, self.context_frames * self.hid_s) < 4:
            raise ClodsError("hid_t and context_frames x hid_s must be >= 4 (the attention's channel gates squeeze by 4)", where=WHERE)
        if min(lka_kernels(self.kernel_size, 3)) < 1:
            raise ClodsError(f"must be >= 3 for a dilation-3 decomposition, got {self.kernel_size}", where=f"{WHERE}.kernel_size")
        if self.mlp_ratio <= 0 or self.alpha < 0 or self.temperature <= 0 or not 0 <= self.drop_path < 1:
            raise ClodsError("mlp_ratio and temperature must be > 0, alpha >= 0, drop_path in [0, 1)", where=WHERE)


class TauPredictor(WindowPredictor[TauConfig]):
    """TAU trained from scratch on the given single-view videos."""

    name = "tau"
    label = "TAU"

    def build_model(self) -> nn.Module:
        """TAU at this config's size."""
        c = self.cfg
        return TAU(c.context_frames, c.hid_s, c.hid_t, c.enc_layers, c.trans_layers, c.kernel_size, c.mlp_ratio, c.drop_path)

    def downsample_factor(self) -> int:
        """2 per pair of encoder layers."""
        return 2 ** (self.cfg.enc_layers // 2)

    def loss(self, model: nn.Module, window: torch.Tensor, step: int, rng: np.random.Generator) -> torch.Tensor:
        """MSE of the next C frames plus alpha x the differential divergence of their frame differences."""
        c = self.cfg.context_frames
        pred, truth = model(window[:, :c]), window[:, c:]
        return torch.nn.functional.mse_loss(pred, truth) + self.cfg.alpha * differential_divergence(pred, truth, self.cfg.temperature)
